"""The port every voice backend implements (``guidance.app.ports`` re-exports it, so the app
is typed with it; the voice never imports the app)."""

from __future__ import annotations

from typing import Protocol

from guidance.core.messages import Health


class Speaker(Protocol):
    """Speaks (or writes) driver prompts; never blocks the caller."""

    def say(self, text: str, priority: int = 0, t_s: float | None = None) -> None: ...
    def close(self, drain: bool = True) -> None:
        """Stop; with ``drain`` finish what is queued first (a WAV file), else cut it."""

    def health(self) -> Health:
        """The voice's record ("ok", "text_fallback" after an engine failure, "stopped")."""
