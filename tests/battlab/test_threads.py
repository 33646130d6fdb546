"""Work over threads: order, errors, the calling thread when one suffices, and compiled simulations side by side
equal to the same simulations one after the other."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from battlab.threads import cores, thread_map


def test_thread_map_keeps_the_order_and_uses_the_calling_thread_for_one_worker() -> None:
    assert cores() >= 1
    assert thread_map(lambda x: x * x, range(7), workers=3) == [x * x for x in range(7)]
    main = threading.get_ident()
    assert thread_map(lambda _: threading.get_ident(), range(3), workers=1) == [main] * 3
    assert thread_map(lambda x: x, []) == []


def test_thread_map_raises_the_first_error() -> None:
    def f(x: int) -> int:
        if x == 2:
            raise ValueError(f"bad {x}")
        return x

    with pytest.raises(ValueError, match="bad 2"):
        thread_map(f, range(4), workers=2)


def test_compiled_simulations_side_by_side_equal_them_one_after_the_other(monkeypatch: pytest.MonkeyPatch) -> None:
    """The extension directions of the diagnosis, run on two threads, are bit-identical to a serial run (the
    compiled stepper keeps its work memory per thread)."""
    import battlab
    import battlab.diagnose.directions as d
    from protocols import Library

    cell = battlab.Cell.load("nca18650")
    prof = Library.build()[37]
    causes = ("contact_resistance", "current_sensor", "hysteresis", "capacity_fade")
    names = ("D_s_n", "k_p")
    args = (cell, prof, prof.soc0, names)

    together = d.extension_directions(*args, causes=causes)
    monkeypatch.setattr(d, "thread_map", lambda fn, xs, workers=None: thread_map(fn, xs, 1))
    alone = d.extension_directions(*args, causes=causes)
    assert [x.cause for x in together] == list(causes)
    for a, b in zip(together, alone, strict=True):
        assert a.cause == b.cause
        np.testing.assert_array_equal(a.J, b.J)
        np.testing.assert_array_equal(a.S, b.S)
        np.testing.assert_array_equal(a.voltage, b.voltage)
