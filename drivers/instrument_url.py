"""A parsed instrument URL: the value the URL parser (:mod:`drivers.urls`) returns and the driver registry
(:mod:`drivers.registry`) hands to a driver's opener."""

from __future__ import annotations

from dataclasses import dataclass, field

from protocols.errors import InputError


@dataclass(frozen=True)
class InstrumentURL:
    """A parsed instrument URL.

    ``scheme`` is a registered scheme (or ``virtual``); ``host``/``port`` for TCP links; ``device`` for serial ports;
    ``options`` the query string (``baud``, ``unit``, ``parity``, ``stopbits``, ``timeout``).
    """

    raw: str
    scheme: str
    host: str | None = None
    port: int | None = None
    device: str | None = None
    options: dict[str, str] = field(default_factory=dict)

    @property
    def pyserial_url(self) -> str:
        """The pyserial ``serial_for_url`` argument for this link (``socket://h:p`` or a device path)."""
        if self.device is not None:
            return self.device
        return f"socket://{self.host}:{self.port}"

    def option(self, key: str, default: str | None = None) -> str | None:
        return self.options.get(key, default)

    def int_option(self, key: str, default: int) -> int:
        value = self.options.get(key)
        if value is None:
            return default
        try:
            return int(value)
        except ValueError:
            raise InputError(f"instrument URL {self.raw!r}: option {key}={value!r} is not an integer") from None

    def float_option(self, key: str, default: float) -> float:
        value = self.options.get(key)
        if value is None:
            return default
        try:
            return float(value)
        except ValueError:
            raise InputError(f"instrument URL {self.raw!r}: option {key}={value!r} is not a number") from None
