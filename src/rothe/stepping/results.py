"""Result codes of a step: an enum whose members carry their message (optimistix ``RESULTS``).

A family defines its codes as a subclass of :class:`ResultCode`, each member with its value (the
short code stored in trajectories and summaries) and its message::

    class RISCode(ResultCode):
        SUCCESSFUL = "ok", "the step's solve converged"
        STALLED = "stalled", "the inner solver stopped making progress"

``RISCode("stalled") is RISCode.STALLED``; ``RISCode.STALLED.message`` is the text;
``str(code)`` is the value, so a code compares equal to its string (``code == "stalled"``) and
serializes as one.
"""

from __future__ import annotations

from enum import Enum


class ResultCode(str, Enum):
    """Base of the families' result codes: ``value`` the code, ``message`` what it means."""

    def __new__(cls, value: str, message: str = ""):
        member = str.__new__(cls, value)
        member._value_ = value
        member.message = message
        return member

    def __str__(self) -> str:
        return str(self.value)

    @property
    def successful(self) -> bool:
        """True for the code of a converged solve ("ok")."""
        return self.value == "ok"
