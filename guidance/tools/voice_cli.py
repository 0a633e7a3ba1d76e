"""``guidance voice say|listen``: one sentence through the car's voice, a WAV through the
co-driver's speech input (issue 39; docs/voice.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from guidance.errors import UserError

SAY_BACKENDS = ("auto", "pico", "espeak")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "voice",
        help="say one sentence into a WAV; run the speech input on a WAV",
        description="The car's voice and its ears, on files (docs/voice.md).",
    )
    vsub = p.add_subparsers(dest="voice_command", metavar="ACTION", required=True)
    say = vsub.add_parser(
        "say",
        help="render one sentence into a WAV with the car's voice",
        description="Render TEXT as the car says it (the same renderer, level and queue as "
        "the car's WAV recording) into a 16-bit mono WAV.",
    )
    say.add_argument("text", metavar="TEXT")
    say.add_argument("--to", required=True, metavar="F.wav", help="the WAV to write")
    say.add_argument(
        "--backend", choices=SAY_BACKENDS, default="auto",
        help="the engine: auto (Pico; espeak-ng for other languages), pico, espeak",
    )  # fmt: skip
    say.add_argument("--voice", default="en", help="language: en, en-gb, de, fr... (default en)")
    say.add_argument("--rate-wpm", type=int, default=170, help="words per minute (default 170)")
    say.add_argument("--volume", type=float, default=1.0, help="0 to 1 (default 1)")
    say.set_defaults(func=_say)
    listen = vsub.add_parser(
        "listen",
        help="the co-driver lines the speech input would produce from a WAV",
        description="Run the co-driver's speech input (pocketsphinx with the co-driver grammar) "
        "on a 16-bit mono WAV and print each co-driver line it would produce, with its time "
        "and confidence; phrases below the confidence threshold are printed as 'say again'.",
    )
    listen.add_argument("wav", metavar="F.wav")
    listen.add_argument("--json", action="store_true",
                        help="one JSON object per line: t_s, line, confidence, heard")  # fmt: skip
    listen.add_argument("--accept", type=float, default=None, metavar="C",
                        help="take phrases from this confidence (default: the car's, "
                        "drivers.speech_grammar.ACCEPT)")  # fmt: skip
    listen.add_argument("--talk", choices=("always", "wake"), default="always",
                        help="always: every stretch of voice is tried (the confidence decides); "
                        "wake: only what follows the wake word 'navigator'")  # fmt: skip
    listen.set_defaults(func=_listen)


def _say(args: argparse.Namespace) -> int:
    from guidance.voice import make_speaker
    from guidance.voice.speakers import TextSpeaker

    if not args.text.strip():
        raise UserError("nothing to say: TEXT is empty")
    if not 80 <= args.rate_wpm <= 400:
        raise UserError(f"--rate-wpm must be within 80 to 400, not {args.rate_wpm}")
    if not 0.0 <= args.volume <= 1.0:
        raise UserError(f"--volume must be within 0 to 1, not {args.volume}")
    spk = make_speaker(
        args.backend, Path(args.to), clock=lambda: 0.0, voice=args.voice,
        rate_wpm=args.rate_wpm, volume=args.volume,
    )  # fmt: skip
    if isinstance(spk, TextSpeaker):
        raise UserError(f"no speech engine: {spk.fallback_reason}")
    spk.say(args.text, 1, 0.0)
    spk.close(drain=True)
    if spk.health().status != "ok":
        raise UserError(f"speech failed: {spk.health().detail}")
    recorded = getattr(spk, "recorded", ())
    seconds = sum(r.duration_s for r in recorded)
    sys.stdout.write(f"{args.to}: {seconds:.2f} s ({getattr(spk, 'renderer_name', '')})\n")
    return 0


def _listen(args: argparse.Namespace) -> int:
    from drivers.speech_grammar import ACCEPT, SAY_AGAIN, CommandRecogniser, read_wav_16k
    from drivers.speech_worker import UtteranceStream

    try:
        pcm = read_wav_16k(args.wav)
    except (OSError, ValueError) as exc:
        raise UserError(f"{args.wav}: {exc}") from None
    accept = ACCEPT if args.accept is None else args.accept
    if not 0.0 <= accept <= 1.0:
        raise UserError(f"--accept must be between 0 and 1, not {accept}")
    stream = UtteranceStream(CommandRecogniser(accept, min(SAY_AGAIN, accept)), args.talk)
    for heard in [o.heard for o in stream.feed(pcm) + stream.flush() if o.heard is not None]:
        if args.json:
            row = {"t_s": round(heard.t_s, 2), "line": heard.line,
                   "confidence": round(heard.confidence, 3), "heard": heard.text}  # fmt: skip
            sys.stdout.write(json.dumps(row) + "\n")
        else:
            what = heard.line or "say again"
            sys.stdout.write(f"{heard.t_s:8.2f} s  {what}  (confidence {heard.confidence:.2f},"
                             f" heard {heard.text!r})\n")  # fmt: skip
    sys.stdout.flush()
    return 0
