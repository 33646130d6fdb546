"""Instrument error types.

:class:`protocols.errors.InputError` stays the one type for a *user's* mistake (a bad URL, a value outside the
instrument's range). Faults that come from the instrument or the link are :class:`InstrumentError`:

- :class:`CommunicationError`: transient link trouble (timeout, disconnect); safe to retry an idempotent
  exchange. :class:`ReplyError` (garbled or unexpected reply) is one of them.
- :class:`InstrumentFault`: the instrument itself reports a problem (error queue, ``NA:`` reply, Modbus
  exception, protection trip, chamber alarm, stability timeout); retrying does not help.

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
