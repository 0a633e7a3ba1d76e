"""Level normalisation of rendered speech: every prompt at the same loudness, whatever the engine.

Pico speaks about 8 dB quieter than espeak-ng and both vary by sentence; a driver should not have
to turn the volume up for one prompt and down for the next. Each rendered prompt is scaled to a
target RMS over its voiced part (samples above a floor), then limited so its peak stays below
full scale (no clipping), then multiplied by the configured ``volume``. One definition: the WAV
recorder and the played voice both call ``normalise_level``.
"""

from __future__ import annotations

import numpy as np

TARGET_RMS_DBFS = -20.0
"""Speech loudness: -20 dBFS RMS (EBU R 128's -23 LUFS programme level plus headroom for a car's
noise; broadcast speech sits at -18 to -23 dBFS)."""
PEAK_LIMIT_DBFS = -1.0
"""No sample above -1 dBFS after scaling (a prompt with a loud plosive is turned down instead)."""
VOICED_BELOW_PEAK_DB = 40.0
"""Samples more than this below the prompt's peak (pauses, silence around it) do not count in
the RMS; relative to the peak, so the measure does not change when the prompt is scaled."""
SILENCE_DBFS = -80.0
"""A prompt whose peak is below this is silence and is left alone."""


def _db(x: float) -> float:
    return float(10.0 ** (x / 20.0))


def normalise_level(pcm: bytes, volume: float = 1.0) -> bytes:
    """16-bit mono PCM scaled to ``TARGET_RMS_DBFS`` over its voiced samples, peak-limited to
    ``PEAK_LIMIT_DBFS``, times ``volume`` (0-1). Silence stays silence."""
    a = np.frombuffer(pcm, dtype="<i2").astype(np.float64) / 32768.0
    if a.size == 0:
        return b""
    rms, peak = _voiced_rms(a)
    if rms <= 0.0:
        return pcm if volume >= 1.0 else _to_pcm(a * max(0.0, volume))
    gain = min(_db(TARGET_RMS_DBFS) / rms, _db(PEAK_LIMIT_DBFS) / peak)
    return _to_pcm(a * gain * min(max(float(volume), 0.0), 1.0))


def _to_pcm(a: np.ndarray) -> bytes:
    return bytes(np.clip(np.round(a * 32768.0), -32768, 32767).astype("<i2").tobytes())


def _voiced_rms(a: np.ndarray) -> tuple[float, float]:
    """(RMS of the voiced samples, peak) of samples in [-1, 1]; (0, peak) for silence."""
    peak = float(np.max(np.abs(a))) if a.size else 0.0
    if peak < _db(SILENCE_DBFS):
        return 0.0, peak
    voiced = a[np.abs(a) > peak * _db(-VOICED_BELOW_PEAK_DB)]
    return float(np.sqrt(np.mean(voiced * voiced))), peak


def rms_dbfs(pcm: bytes) -> float:
    """The RMS level of the voiced samples of 16-bit PCM in dBFS (-inf for silence)."""
    rms, _ = _voiced_rms(np.frombuffer(pcm, dtype="<i2").astype(np.float64) / 32768.0)
    return float(20.0 * np.log10(rms)) if rms > 0 else float("-inf")
