"""SIGTERM during training: a flag the loop polls, so that it saves a checkpoint and stops."""

import signal
import threading
from types import FrameType
from typing import Any


class SigtermFlag:
    """Context manager: while active (and `enabled`, in the main thread), SIGTERM sets `.set`."""

    def __init__(self, enabled: bool) -> None:
        self.set = False
        self._old: Any = None
        self.enabled = enabled and threading.current_thread() is threading.main_thread()

    def __enter__(self) -> "SigtermFlag":
        if self.enabled:
            self._old = signal.signal(signal.SIGTERM, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.set = True

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            signal.signal(signal.SIGTERM, self._old)
