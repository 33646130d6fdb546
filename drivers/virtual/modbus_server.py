"""The virtual Watlow F4T: pymodbus ≥ 3.16 servers (Modbus TCP, and RTU framing over TCP) on the lab chamber.

pymodbus's server is asyncio-only: it runs in its own thread with its own event loop; everything else in the
virtual tester is threads with blocking sockets. The register map is :mod:`drivers.chambers.watlow_codec`'s;
the ``action`` hook of pymodbus's ``SimDevice`` computes the process value on each read and applies set-point
writes to the lab's chamber (under the lab's lock). Link faults are injected on the reply path
(``trace_packet``): lost reply, corrupted frame (Modbus TCP: the function code, so the client notices;
RTU: any byte, so the CRC fails), delayed reply, disconnect.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.chambers import watlow_codec as wc
from drivers.virtual.faults import Fault, FaultInjector
from drivers.virtual.instruments import ExecutionError
from drivers.virtual.served import ServedLab

#: the longest wait for one Modbus server to shut down [s]
SHUTDOWN_TIMEOUT_S = 1.0
log = logging.getLogger("drivers.virtual")


class F4TModbusServer:
    """Watlow F4T loop 1 on Modbus TCP (``tcp_port``) and RTU-over-TCP (``rtu_port``; None: off)."""

    def __init__(
        self,
        lab: ServedLab,
        *,
        host: str = "127.0.0.1",
        tcp_port: int | None = 0,
        rtu_port: int | None = 0,
        unit: int = 1,
        faults: FaultInjector | None = None,
        units: int = wc.UNITS_C,
        part_number: str = "F4T1L1AA1A2AAAA",
    ) -> None:
        self.lab = lab
        self.host = host
        self.requested = {"tcp": tcp_port, "rtu": rtu_port}
        self.unit = unit
        self.faults = faults or FaultInjector()
        self.display_units = units
        self.part_number = part_number
        self.ports: dict[str, int] = {}
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._servers: list[ModbusTcpServer] = []

    @property
    def tcp_url(self) -> str:
        return f"modbus-tcp://{self.host}:{self.ports['tcp']}?unit={self.unit}"

    @property
    def rtu_url(self) -> str:
        return f"modbus-rtu+socket://{self.host}:{self.ports['rtu']}?unit={self.unit}"

    # -- registers ----------------------------------------------------------------------------------------
    def _device(self) -> SimDevice:
        sp = self.lab.chamber.sp_K - 273.15
        c = self.lab.chamber.config
        conv = (lambda x: x) if self.display_units == wc.UNITS_C else wc.c_to_f
        data = [
            SimData(wc.HARDWARE_ID, values=[124, 0], datatype=DataType.REGISTERS, readonly=True),
            SimData(
                wc.PART_NUMBER,
                values=wc.encode_string(self.part_number, wc.PART_NUMBER_LENGTH),
                datatype=DataType.REGISTERS,
                readonly=True,
            ),
            SimData(wc.DISPLAY_UNITS, values=[self.display_units], datatype=DataType.REGISTERS, readonly=True),
            SimData(wc.ALARM1_STATE, values=[61], datatype=DataType.REGISTERS, readonly=True),
            SimData(wc.CONTROL_MODE, values=[wc.MODE_AUTO], datatype=DataType.REGISTERS),
            SimData(
                wc.RANGE_LOW,
                values=wc.encode_float(conv(c.sp_min_C)),
                datatype=DataType.REGISTERS,
                readonly=True,
            ),
            SimData(
                wc.RANGE_HIGH,
                values=wc.encode_float(conv(c.sp_max_C)),
                datatype=DataType.REGISTERS,
                readonly=True,
            ),
            SimData(wc.SET_POINT, values=wc.encode_float(conv(sp)), datatype=DataType.REGISTERS),
            SimData(wc.PROCESS_VALUE, values=wc.encode_float(conv(sp)), datatype=DataType.REGISTERS, readonly=True),
        ]
        return SimDevice(id=self.unit, simdata=data, action=self._action)

    async def _action(
        self,
        function_code: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        conv_out = (lambda x: x) if self.display_units == wc.UNITS_C else wc.c_to_f
        conv_in = (lambda x: x) if self.display_units == wc.UNITS_C else wc.f_to_c
        end = address + count

        def covers(reg: int, n: int = 2) -> bool:
            return address < reg + n and reg < end

        with self.lab.lock:
            self.lab.exchange()
            ch = self.lab.chamber
            if values is None:  # read: refresh the live registers
                if covers(wc.PROCESS_VALUE):
                    registers[wc.PROCESS_VALUE - start : wc.PROCESS_VALUE - start + 2] = wc.encode_float(
                        conv_out(ch.read_C())
                    )
                if covers(wc.ALARM1_STATE, 1):
                    registers[wc.ALARM1_STATE - start] = wc.ALARM_ACTIVE_SIM if ch.alarm_codes else 61
                if covers(wc.CONTROL_MODE, 1):
                    registers[wc.CONTROL_MODE - start] = wc.MODE_AUTO if ch.running else wc.MODE_OFF
                return None
            vals = [int(v) for v in values]
            if covers(wc.SET_POINT):
                if address != wc.SET_POINT or count != 2:
                    return ExcCodes.ILLEGAL_VALUE
                try:
                    T_C = conv_in(wc.decode_float(vals, instrument="virtual F4T", what="set point"))
                    ch.set_point_C(T_C)
                except (ExecutionError, ValueError):
                    return ExcCodes.ILLEGAL_VALUE
            if covers(wc.CONTROL_MODE, 1):
                mode = vals[wc.CONTROL_MODE - address]
                if mode not in (wc.MODE_AUTO, wc.MODE_MANUAL, wc.MODE_OFF):
                    return ExcCodes.ILLEGAL_VALUE
                if mode == wc.MODE_AUTO and ch.alarm_codes:
                    return ExcCodes.DEVICE_FAILURE
                ch.running = mode == wc.MODE_AUTO
            return None

    # -- faults on the reply path -------------------------------------------------------------------------
    def _trace(self, kind: str) -> Callable[[bool, bytes], bytes]:
        def trace(sending: bool, data: bytes) -> bytes:
            if not sending:
                return data
            fault = self.faults.next_fault()
            if fault in (Fault.DROP, Fault.LOSE_REPLY):
                return b""
            if fault is Fault.DELAY:
                time.sleep(self.faults.config.delay_s)
            elif fault is Fault.GARBLE:
                if kind == "tcp":  # corrupt the function code: TCP has no CRC of its own at this level
                    out = bytearray(data)
                    if len(out) > 7:
                        out[7] = 0x7F
                    return bytes(out)
                return self.faults.garble_bytes(data)
            elif fault is Fault.DISCONNECT:
                assert self._loop is not None
                self._loop.call_soon(self._disconnect_all)
                return b""
            return data

        return trace

    def _disconnect_all(self) -> None:
        for server in self._servers:
            for conn in list(server.active_connections.values()):
                conn.close()

    # -- thread and loop ----------------------------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> None:
        self._thread = threading.Thread(target=self._run, name="virtual-f4t-modbus", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError("virtual F4T: Modbus servers did not start in time")
        if self._error is not None:
            raise RuntimeError(f"virtual F4T: Modbus servers failed to start: {self._error}") from self._error

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        except BaseException as exc:  # reported to start()
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _main(self) -> None:
        self._stop = asyncio.Event()
        for kind, framer in (("tcp", FramerType.SOCKET), ("rtu", FramerType.RTU)):
            port = self.requested[kind]
            if port is None:
                continue
            server = ModbusTcpServer(
                self._device(), framer=framer, address=(self.host, port), trace_packet=self._trace(kind)
            )
            await server.serve_forever(background=True)
            self.ports[kind] = server.transport.sockets[0].getsockname()[1]  # type: ignore[union-attr]
            self._servers.append(server)
        log.info("virtual F4T listening: %s", self.ports)
        self._ready.set()
        await self._stop.wait()
        for server in self._servers:
            # pymodbus's shutdown waits for its client connections: bounded, so that Ctrl-C of a served lab
            # cannot hang on a client that went away mid-exchange
            with contextlib.suppress(TimeoutError, asyncio.TimeoutError):
                await asyncio.wait_for(server.shutdown(), SHUTDOWN_TIMEOUT_S)

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._loop is not None and self._stop is not None and not self._loop.is_closed():
            with contextlib.suppress(RuntimeError):
                self._loop.call_soon_threadsafe(self._stop.set)
        if self._thread is not None:
            self._thread.join(timeout_s)
