"""Data files: simulation results, our HDF5 run log, BDF CSV and the Panasonic 18650PF ``.mat`` files.

``load_data(path)`` reads any of them as :class:`LoggedData` (BDF columns + metadata) after checking it;
``open_log``/``read_log`` are the run log's writer and reader (see :mod:`battlab.io.logs`).
"""

from battlab.io.data import LoggedData, load_data
from battlab.io.logs import LogWriter, open_log, read_log, run_meta

__all__ = ["LogWriter", "LoggedData", "load_data", "open_log", "read_log", "run_meta"]
