"""Instrument error types.

:class:`protocols.errors.InputError` stays the one type for a *user's* mistake (a bad URL, a value outside the
instrument's range). Faults that come from the instrument or the link are :class:`InstrumentError`:

- :class:`CommunicationError`: transient link trouble (timeout, disconnect); safe to retry an idempotent
  exchange. :class:`ReplyError` (garbled or unexpected reply) is one of them.
- :class:`InstrumentFault`: the instrument itself reports a problem (error queue, ``NA:`` reply, Modbus
  exception, protection trip, chamber alarm, stability timeout); retrying does not help.

:class:`NotSupported` is neither: the instrument lacks an operation (no watchdog, no low-voltage cut-off, ...). A
driver declares what it has in its ``capabilities`` (:mod:`drivers.interfaces`) and raises this, before any I/O, when
asked for what it declared it lacks; callers ask the capabilities first.

Every message names the instrument and, where there is one, the reply.
"""

from __future__ import annotations


class InstrumentError(Exception):
    """A fault of an instrument or of the link to it."""

    def __init__(self, instrument: str, message: str, *, reply: str | bytes | None = None) -> None:
        self.instrument = instrument
        self.detail = message
        self.reply = reply
        text = f"{instrument}: {message}"
        if reply is not None:
            text += f" (reply {reply!r})"
        super().__init__(text)


class CommunicationError(InstrumentError):
    """Transient link failure (timeout, disconnect, garbled bytes): an idempotent exchange may be retried."""


class ReplyError(CommunicationError):
    """A reply that cannot be parsed or is not what the command expects."""


class InstrumentFault(InstrumentError):
    """The instrument reports an error or a safety condition; retrying does not help."""

    def __init__(
        self,
        instrument: str,
        message: str,
        *,
        reply: str | bytes | None = None,
        causes: tuple[str, ...] = (),
    ) -> None:
        self.causes = causes
        super().__init__(instrument, message, reply=reply)


class NotSupported(Exception):
    """The instrument lacks ``operation``: not a user's mistake (:class:`protocols.errors.InputError`) and not a fault
    of the instrument or the link (:class:`InstrumentError`). Raised before any I/O."""

    def __init__(self, instrument: str, operation: str, why: str = "") -> None:
        self.instrument = instrument
        self.operation = operation
        self.why = why
        super().__init__(f"{instrument}: {operation} is not supported" + (f" ({why})" if why else ""))
