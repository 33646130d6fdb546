"""Modbus holding-register access through pymodbus ≥ 3.16 (sync clients), with the port lock and logging.

pymodbus 3.x renamed ``slave=`` to ``device_id=``: calls here are
``client.read_holding_registers(address, count=n, device_id=unit)`` and
``client.write_registers(address, values, device_id=unit)``. pymodbus's own retries are off (``retries=0``);
:func:`drivers.transport.with_retries` retries at this level so that every attempt is logged in one place.
"""

from __future__ import annotations

import time
from typing import Protocol

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from drivers.errors import CommunicationError, InstrumentFault, ReplyError
from drivers.transport import log_exchange, port_lock, with_retries
from drivers.urls import InstrumentURL

_EXCEPTIONS = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "device failure",
    6: "device busy",
    11: "gateway target failed to respond",
}


class RegisterAdapter(Protocol):
    """What a Modbus device driver needs: holding registers by address."""

    name: str
    #: extra attempts for a transaction that failed on the link (settable)
    retries: int

    def read(self, address: int, count: int) -> list[int]: ...

    def write(self, address: int, values: list[int]) -> None: ...

    def close(self) -> None: ...


class PymodbusRegisters:
    """Holding registers of device ``unit`` over a pymodbus sync client (TCP, RTU, or RTU over a socket)."""

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        *,
        name: str,
        lock_key: str,
        unit: int = 1,
        retries: int = 2,
    ) -> None:
        self.client = client
        self.name = name
        self.unit = unit
        self.retries = retries
        self.lock = port_lock(lock_key)

    @classmethod
    def from_url(
        cls, url: InstrumentURL, *, name: str | None = None, timeout_s: float | None = None, retries: int = 2
    ) -> PymodbusRegisters:
        timeout = timeout_s if timeout_s is not None else url.float_option("timeout", 1.0)
        unit = url.int_option("unit", 1)
        client: ModbusTcpClient | ModbusSerialClient
        if url.scheme == "modbus-tcp":
            assert url.host is not None and url.port is not None
            client = ModbusTcpClient(url.host, port=url.port, timeout=timeout, retries=0)
            key = f"socket://{url.host}:{url.port}"
        elif url.scheme == "modbus-rtu+socket":
            key = url.pyserial_url
            client = ModbusSerialClient(key, framer=FramerType.RTU, timeout=timeout, retries=0)
        elif url.scheme == "modbus-rtu":
            assert url.device is not None
            key = url.device
            client = ModbusSerialClient(
                url.device,
                framer=FramerType.RTU,
                baudrate=url.int_option("baud", 9600),
                parity=url.option("parity", "N") or "N",
                stopbits=url.int_option("stopbits", 1),
                timeout=timeout,
                retries=0,
            )
        else:
            raise ValueError(f"not a Modbus URL: {url.raw}")
        return cls(client, name=name or url.raw, lock_key=key, unit=unit, retries=retries)

    def _connect(self) -> None:
        if not self.client.connected and not self.client.connect():
            raise CommunicationError(self.name, "cannot connect")

    def _recover(self) -> None:
        with self.lock:
            self.client.close()
            time.sleep(0.01)

    def _call(self, what: str, fn: str, address: int, *args: object, **kwargs: object) -> object:
        def attempt() -> object:
            with self.lock:
                t0 = time.perf_counter()
                try:
                    self._connect()
                    response = getattr(self.client, fn)(address, *args, device_id=self.unit, **kwargs)
                except (ModbusIOException, ConnectionException) as exc:
                    log_exchange(self.name, what, None, time.perf_counter() - t0, f"FAILED: {exc}")
                    raise CommunicationError(self.name, f"{what}: {exc}") from exc
                except ModbusException as exc:
                    log_exchange(self.name, what, None, time.perf_counter() - t0, f"FAILED: {exc}")
                    raise ReplyError(self.name, f"{what}: {exc}") from exc
                elapsed = time.perf_counter() - t0
                log_exchange(self.name, what, response, elapsed)
                if response.isError():
                    code = getattr(response, "exception_code", None)
                    raise InstrumentFault(
                        self.name,
                        f"{what}: Modbus exception {code} ({_EXCEPTIONS.get(code or 0, 'unknown')})",
                    )
                return response

        return with_retries(self.name, what, attempt, retries=self.retries, recover=self._recover)

    def read(self, address: int, count: int) -> list[int]:
        what = f"read {count} register(s) at {address}"
        response = self._call(what, "read_holding_registers", address, count=count)
        registers = list(getattr(response, "registers", []))
        if len(registers) != count:
            raise ReplyError(self.name, f"{what}: got {len(registers)} registers", reply=repr(registers))
        return registers

    def write(self, address: int, values: list[int]) -> None:
        self._call(f"write {values} at {address}", "write_registers", address, list(values))

    def close(self) -> None:
        with self.lock:
            self.client.close()
