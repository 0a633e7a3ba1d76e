"""espeak-ng as a library from the package index (``espeakng-loader``): speech without root.

A fresh machine without the Debian package espeak-ng still speaks: the ``espeakng-loader``
wheel ships libespeak-ng and its voice data, and this renderer drives the library through
ctypes in synchronous mode (the samples come back through a callback; no audio device). The
command line (``EspeakNgRenderer``) stays first choice where it is installed: a crash there is
an exit status, not a dead process. The library keeps global state, so one lock serialises
every call.
"""

from __future__ import annotations

import ctypes
import threading
from typing import Any

from guidance.voice.queue import DEFAULT_RATE_WPM
from guidance.voice.speakers import SpeechEngineError

_AUDIO_OUTPUT_SYNCHRONOUS = 2
_POS_CHARACTER = 1
_ESPEAK_CHARS_UTF8 = 1
_ESPEAK_RATE = 1
_EE_OK = 0
_MAX_SECONDS = 60.0
"""A prompt longer than this is cut (a runaway text must not fill memory)."""

_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int,
                             ctypes.c_void_p)  # fmt: skip

_LOCK = threading.Lock()
_LIB: Any = None
_RATE_HZ = 0


def available() -> bool:
    """True when the espeakng-loader wheel is installed (it may still fail to load)."""
    try:
        import espeakng_loader  # noqa: F401
    except ImportError:
        return False
    return True


def _load() -> tuple[Any, int]:
    global _LIB, _RATE_HZ
    if _LIB is not None:
        return _LIB, _RATE_HZ
    try:
        import espeakng_loader
    except ImportError:
        raise SpeechEngineError(
            "no espeak-ng: install the Debian package espeak-ng or the wheel espeakng-loader"
        ) from None
    try:
        lib = ctypes.CDLL(espeakng_loader.get_library_path())
        data = espeakng_loader.get_data_path().encode()
    except (OSError, RuntimeError) as exc:
        raise SpeechEngineError(f"espeak-ng library failed to load: {exc}") from None
    lib.espeak_Initialize.restype = ctypes.c_int
    lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    rate = int(lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 500, data, 0))
    if rate <= 0:
        raise SpeechEngineError(f"espeak-ng library did not start (code {rate})")
    lib.espeak_SetSynthCallback.argtypes = [_CALLBACK]
    lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
    lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lib.espeak_Synth.argtypes = [
        ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int, ctypes.c_uint,
        ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p,
    ]  # fmt: skip
    _LIB, _RATE_HZ = lib, rate
    return lib, rate


class LibEspeakRenderer:
    """Renders text to 16-bit mono PCM with the espeak-ng library (the ``Renderer`` shape)."""

    def __init__(self, voice: str = "en", rate_wpm: int = DEFAULT_RATE_WPM) -> None:
        self._voice = voice.encode()
        self._rate_wpm = int(rate_wpm)
        with _LOCK:
            _load()

    def __call__(self, text: str) -> tuple[bytes, int]:
        chunks: list[bytes] = []
        with _LOCK:
            lib, rate = _load()
            limit = int(_MAX_SECONDS * rate) * 2

            def collect(wav: Any, n: int, _events: Any) -> int:
                if wav and n > 0 and sum(map(len, chunks)) < limit:
                    chunks.append(ctypes.string_at(wav, n * 2))
                return 0  # 0: continue

            callback = _CALLBACK(collect)  # kept alive for the call below
            lib.espeak_SetSynthCallback(callback)
            if lib.espeak_SetVoiceByName(self._voice) != _EE_OK:
                raise SpeechEngineError(f"espeak-ng has no voice {self._voice.decode()!r}")
            lib.espeak_SetParameter(_ESPEAK_RATE, self._rate_wpm, 0)
            body = text.encode("utf-8") + b"\0"
            buf = ctypes.create_string_buffer(body)
            err = lib.espeak_Synth(buf, len(body), 0, _POS_CHARACTER, 0, _ESPEAK_CHARS_UTF8,
                                   None, None)  # fmt: skip
            if err != _EE_OK:
                raise SpeechEngineError(f"espeak-ng library failed (code {err})")
        return b"".join(chunks)[:limit], rate
