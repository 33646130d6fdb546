"""The virtual Espec P-300: its text protocol (CR LF lines) on a loopback socket, on the lab chamber."""

from __future__ import annotations

from drivers.chambers import espec_codec as ec
from drivers.virtual.faults import FaultInjector
from drivers.virtual.instruments import ExecutionError
from drivers.virtual.served import ServedLab
from drivers.virtual.textserver import LineServer


class EspecServer:
    """Answers ``TEMP?``, ``TEMP, S…``, ``MODE, …``, ``MODE?``, ``MON?``, ``ALARM?``, ``TYPE?``, ``ROM?``."""

    def __init__(
        self, lab: ServedLab, *, host: str = "127.0.0.1", port: int = 0, faults: FaultInjector | None = None
    ) -> None:
        self.lab = lab
        self.server = LineServer(
            "virtual-espec",
            self.handle,
            host=host,
            port=port,
            read_terminator="\n",
            write_terminator="\r\n",
            faults=faults,
        )

    @property
    def url(self) -> str:
        return f"espec://{self.server.host}:{self.server.port}"

    def start(self) -> None:
        self.server.start()

    def stop(self) -> None:
        self.server.stop()

    def _mode(self) -> str:
        ch = self.lab.chamber
        if ch.alarm_codes:
            return "STANDBY"
        return "CONSTANT" if ch.running else "STANDBY"

    def handle(self, line: str) -> str:
        cmd = line.strip()
        upper = cmd.upper()
        with self.lab.lock:
            self.lab.exchange()
            ch = self.lab.chamber
            c = ch.config
            if upper == "TEMP?":
                return ec.format_temp(ec.TempStatus(ch.read_C(), ch.sp_K - 273.15, c.sp_max_C, c.sp_min_C))
            if upper == "MON?":
                return ec.format_mon(ec.MonStatus(ch.read_C(), None, self._mode(), len(ch.alarm_codes)))
            if upper == "ALARM?":
                return ec.format_alarm(list(ch.alarm_codes))
            if upper == "MODE?":
                return self._mode()
            if upper == "TYPE?":
                return f"T,P300,{c.sp_max_C:.0f}"
            if upper == "ROM?":
                return "P-300 VER 1.00 (battlab virtual)"
            setting = ec.parse_set_temp(cmd)
            if setting is not None:
                if set(setting) != {"S"}:
                    return "NA:PARA ERR"
                try:
                    ch.set_point_C(setting["S"])
                except ExecutionError:
                    return "NA:DATA OUT OF RANGE"
                return f"OK: {cmd}"
            mode = ec.parse_mode(cmd)
            if mode is not None:
                if mode not in ("CONSTANT", "STANDBY", "OFF"):
                    return "NA:PARA ERR"
                if mode == "CONSTANT" and ch.alarm_codes:
                    return "NA:CHB NOT READY"
                ch.running = mode == "CONSTANT"
                return f"OK: {cmd}"
            return "NA:CMD ERR"
