"""The commands the docs show are the program's (issue 24, item 6).

Every ``guidance ...`` and ``landmark-db ...`` command in README.md, docs/*.md and
systemd/README.md (fenced blocks, with their continuation lines, and inline code spans) is
checked against the program's own ``--help``: the (sub)command exists, each ``--option`` it
names is in that command's help, and the words it gives for a choice (``--method hybrid``,
``study range|landmarks``) are among the choices. The cheap ones whose files are all there are
run in full; the facts the docs state about a few commands (the defaults in ``guidance sim
--help``, seed 7's drive, which config ``guidance run`` refuses) are checked by running them.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "systemd/README.md")
PROGRAMS = ("guidance", "landmark-db")
_COMMAND = re.compile(rf"^({'|'.join(map(re.escape, PROGRAMS))})\s+\S")
_OPTION = re.compile(r"(?<![\w-])--[A-Za-z0-9][\w-]*")


@dataclass(frozen=True)
class DocCommand:
    where: str
    """file:line"""
    text: str


def doc_commands(path: Path) -> list[DocCommand]:
    """The commands ``path`` shows: fenced lines starting with a program (a command's indented
    next lines continue it), and inline code spans that start with one."""
    text = path.read_text()
    name = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
    out: list[DocCommand] = []
    for m in re.finditer(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M):
        first = text.count("\n", 0, m.start(1)) + 1
        current: list[str] | None = None
        for k, line in enumerate(m.group(1).replace("\\\n", " \n").splitlines()):
            bare = line.strip().removeprefix("$ ")
            if _COMMAND.match(bare):
                current = [bare]
                out.append(DocCommand(f"{name}:{first + k}", ""))
            elif current is not None and line[:1].isspace() and bare:
                current.append(bare)
            else:
                current = None
            if current is not None:
                out[-1] = DocCommand(out[-1].where, " ".join(current))
    prose = re.sub(r"^```.*?^```", lambda m: "\n" * m.group(0).count("\n"), text,
                   flags=re.S | re.M)  # fmt: skip
    for m in re.finditer(r"`([^`]+)`", prose):
        span = " ".join(m.group(1).split())
        if _COMMAND.match(span):
            out.append(DocCommand(f"{name}:{prose.count(chr(10), 0, m.start()) + 1}", span))
    return out


def _tokens(text: str) -> list[str]:
    text = re.sub(r"\s#\s.*$", "", text)  # a trailing comment
    text = text.replace("\\|", "|")  # a pipe escaped in a Markdown table
    return [t for t in re.sub(r"[\[\]()]", " ", text).split() if t]


@cache
def _parser(program: str) -> argparse.ArgumentParser:
    if program == "guidance":
        from guidance.tools.cli import build_parser
    else:
        from landmark_db.cli import build_parser
    return build_parser()


def _main(program: str) -> Callable[[Sequence[str]], int]:
    if program == "guidance":
        from guidance.tools.cli import main
    else:
        from landmark_db.cli import main
    return main


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


@cache
def help_text(path: tuple[str, ...]) -> str:
    """What ``PROGRAM SUB ... --help`` prints (run in-process)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as done:
        _main(path[0])([*path[1:], "--help"])
    assert done.value.code in (0, None), f"{' '.join(path)} --help exited {done.value.code}"
    return out.getvalue()


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in parser._actions for s in a.option_strings}


def problems(cmd: DocCommand) -> list[str]:
    """What in ``cmd`` the program does not have: one line each."""
    toks = _tokens(cmd.text)
    parser, path = _parser(toks[0]), [toks[0]]
    say = f"{cmd.where}: `{cmd.text}`:"
    i = 1
    while i < len(toks) and (subs := _subcommands(parser)):
        word = toks[i]
        if word.endswith(":"):  # an output line ("guidance run: error: ..."), not a command
            return []
        if word in subs:
            parser = subs[word]
            path.append(word)
            i += 1
            continue
        if word != "..." and not word.startswith("-") and re.fullmatch(r"[a-z][a-z-]*", word):
            return [f"{say} `{' '.join(path)} {word}` is no command ({', '.join(subs)})"]
        break
    known = set(_OPTION.findall(help_text(tuple(path))))
    actions = _options(parser)
    found: list[str] = []
    positional_choices = [
        a.choices
        for a in parser._actions
        if not a.option_strings and a.choices and not isinstance(a, argparse._SubParsersAction)
    ]
    rest = toks[i:]
    first = rest[0] if rest else ""
    if positional_choices and ("|" in first or re.fullmatch(r"[a-z][a-z_-]*", first)):
        for word in first.split("|"):
            if word != "..." and word not in positional_choices[0]:
                found.append(f"{say} `{word}` is not one of {' '.join(path)}'s choices")
    for k, tok in enumerate(rest):
        for opt in _OPTION.findall(tok.split("=", 1)[0]):
            if opt not in known:
                found.append(f"{say} {opt} is not in `{' '.join(path)} --help`")
                continue
            choices = actions[opt].choices if opt in actions else None
            value = (
                tok.split("=", 1)[1] if "=" in tok else (rest[k + 1] if k + 1 < len(rest) else "")
            )
            words = value.split("|")
            if choices and all(re.fullmatch(r"[a-z][a-z0-9_-]*", w) for w in words):
                found += [
                    f"{say} {opt} {w}: not one of {', '.join(map(str, choices))}"
                    for w in words
                    if w not in choices
                ]
    return found


def all_doc_commands() -> Iterator[DocCommand]:
    for path in DOC_FILES:
        if path.exists():
            yield from doc_commands(path)


# ----------------------------------------------------------------------------- the checks


def _all_options(parser: argparse.ArgumentParser) -> set[str]:
    out = set(_options(parser))
    for sub in _subcommands(parser).values():
        out |= _all_options(sub)
    return out


def test_an_option_named_alone_in_the_prose_exists() -> None:
    """A span such as `--decision-distance` or `--no-nice` is an option of ``guidance``,
    ``landmark-db`` (any subcommand) or of a benchmark script (benchmarks/*.py)."""
    known = _all_options(_parser("guidance")) | _all_options(_parser("landmark-db"))
    scripts = "\n".join(p.read_text() for p in sorted((ROOT / "benchmarks").glob("*.py")))
    found = []
    for path in DOC_FILES:
        text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        for m in re.finditer(r"`(--[A-Za-z0-9][\w-]*)[^`]*`", text):
            opt = m.group(1)
            if opt not in known and f'"{opt}"' not in scripts:
                found.append(f"{path.relative_to(ROOT)}: {m.group(0)}: no command has {opt}")
    assert not found, "\n".join(found)


def test_the_docs_show_commands_at_all() -> None:
    cmds = list(all_doc_commands())
    readme = [c for c in cmds if c.where.startswith("README.md")]
    assert len(readme) >= 14, readme  # the command table
    assert any("guidance sim [--seed S]" in c.text and "--decision-distance M" in c.text
               for c in cmds), "a fenced command's continuation lines were not joined"  # fmt: skip


def test_every_command_the_docs_show_is_in_the_programs_help() -> None:
    found = [p for c in all_doc_commands() for p in problems(c)]
    assert not found, "\n".join(found)


@pytest.mark.parametrize(
    ("text", "complaint"),
    [
        ("guidance sim --seed 3 --no-such-flag", "--no-such-flag is not in `guidance sim --help`"),
        ("guidance simulate --seed 3", "`guidance simulate` is no command"),
        ("guidance study range|sideways [--check-paper]", "`sideways` is not one of"),
        ("guidance sim [--method hybrid|teleport]", "--method teleport: not one of"),
        ("guidance run --config car.toml [--screen live\\|fancy]", "--screen fancy: not one of"),
        ("guidance recording mend IN OUT", "`guidance recording mend` is no command"),
        ("landmark-db query city.sqlite --near X Y", "--near is not in `landmark-db query"),
    ],
)
def test_a_drift_is_caught(text: str, complaint: str) -> None:
    found = problems(DocCommand("doc.md:1", text))
    assert any(complaint in p for p in found), found


def test_a_true_command_is_not_flagged() -> None:
    for text in (
        "guidance study range\\|landmarks\\|interference\\|field [--check-paper]",
        "guidance run --config car.toml [--screen live\\|plain]",
        "guidance monitor: tcp/127.0.0.1:17471",  # output, not a command
        "landmark-db add city.sqlite photo.jpg (--latlon LAT LON | --xy X Y) [--name N]",
    ):
        assert problems(DocCommand("doc.md:1", text)) == [], text


def test_the_top_level_help_names_every_study() -> None:
    study = _subcommands(_parser("guidance"))["study"]
    choices = next(a.choices for a in study._actions if not a.option_strings and a.choices)
    line = " ".join(help_text(("guidance",)).split("study", 1)[1].split("sim", 1)[0].split())
    assert all(str(c) in line for c in choices), (line, choices)


def test_the_defaults_guidance_sim_help_states_are_the_drives() -> None:
    from hal_sim.drive_options import DriveOptions

    fields = {"--seed": "seed", "--method": "method", "--compass-deg": "compass_deg",
              "--density": "density_per_km2", "--detection-rate": "detection_rate",
              "--decision-distance": "decision_distance_m", "--out": "out"}  # fmt: skip
    sim = _options(_subcommands(_parser("guidance"))["sim"])
    defaults = DriveOptions()
    for flag, field in fields.items():
        text = sim[flag].help or ""
        m = re.search(r"\((?:default )?([\w./]+)[:)]", text)
        assert m, f"guidance sim {flag}: its help names no default: {text!r}"
        value = getattr(defaults, field)
        stated = type(value)(m.group(1)) if isinstance(value, int | float) else m.group(1)
        assert stated == value, f"guidance sim {flag}: help says {m.group(1)}, default {value}"


def _run(*argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "guidance.tools.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def _run_here(*argv: str) -> subprocess.CompletedProcess[str]:
    """``guidance ARGV`` in this process, from the repository's folder (the docs' paths are
    relative to it): cheaper than a new interpreter for a quick command."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(ROOT), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = _main("guidance")(list(argv))
    return subprocess.CompletedProcess(list(argv), code, out.getvalue(), err.getvalue())


def test_the_configs_the_docs_name_for_guidance_run(tmp_path: Path) -> None:
    """docs/app.md: config/tahoe.toml is the example for ``guidance run``; config/sim.toml is
    for ``guidance sim --config`` and ``guidance run`` refuses it ("[goal] is required")."""
    app = (ROOT / "docs" / "app.md").read_text()
    assert "config/tahoe.toml" in app and "config/sim.toml" in app
    tahoe = _run_here("run", "--config", str(ROOT / "config" / "tahoe.toml"), "--check")
    assert tahoe.returncode == 0 and ": OK (vehicle" in tahoe.stdout, tahoe.stderr
    sim = _run_here("run", "--config", str(ROOT / "config" / "sim.toml"), "--check")
    assert sim.returncode == 2 and "[goal] is required" in sim.stderr, sim.stderr
    assert "[goal] is required" in app
    lm = _run_here("run", "--config", str(ROOT / "config" / "sim-landmarks.toml"), "--check")
    assert lm.returncode == 0 and ": OK (vehicle simlm1" in lm.stdout, lm.stderr
    if not (ROOT / "out" / "sim-landmarks" / "landmarks.sqlite").exists():  # built on first use
        assert "build it on first use" in lm.stderr, lm.stderr


def test_seed_7_drives_as_docs_app_md_says(tmp_path: Path) -> None:
    app = (ROOT / "docs" / "app.md").read_text()
    m = re.search(r"Seed 7\s+arrives after ([\d.]+) km in (\d+) simulated seconds", app)
    assert m, "docs/app.md no longer says how seed 7 drives"
    done = _run("sim", "--json", "--no-png", "--no-record", "--no-telemetry", "--no-voice",
                "--out", str(tmp_path), cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    assert result["seed"] == 7 and result["outcome"] == "arrived"
    assert f"{result['driven_km']:.2f}" == m.group(1), result
    assert f"{result['sim_s']:.0f}" == m.group(2), result


def _runnable(cmd: DocCommand) -> list[str] | None:
    """The argv of a doc command that is cheap and complete here: a file command (odometry,
    compass, evaluate, calibrate without --write, run --check) whose every argument is given
    and every file exists; else None."""
    toks = _tokens(cmd.text)
    if toks[0] != "guidance" or len(toks) < 3 or "--write" in toks:
        return None
    if toks[1] not in ("odometry", "compass", "evaluate", "calibrate", "run"):
        return None
    if toks[1] == "run" and "--check" not in toks:
        return None
    for t in toks[2:]:
        if "|" in t or "..." in t or re.fullmatch(r"[A-Z][A-Z0-9_.]*", t):
            return None  # a placeholder
        is_file = "/" in t or re.search(r"\.(log|toml|csv|nmea|txt|mcap)$", t)
        if is_file and not t.startswith("-") and not (ROOT / t).exists():
            return None
    try:  # a fragment named in prose ("`guidance run --check`") is not a whole command
        with contextlib.redirect_stderr(io.StringIO()):
            _parser("guidance").parse_args(toks[1:])
    except SystemExit:
        return None
    return toks[1:]


def test_the_cheap_commands_the_docs_show_run() -> None:
    ran = []
    for cmd in all_doc_commands():
        argv = _runnable(cmd)
        if argv is None:
            continue
        done = _run_here(*argv)
        assert done.returncode == 0, f"{cmd.where}: `{cmd.text}`:\n{done.stderr[-2000:]}"
        assert "Traceback" not in done.stderr, f"{cmd.where}: {done.stderr[-2000:]}"
        ran.append(cmd.where)
    assert ran, "no command of the docs could be run here"
