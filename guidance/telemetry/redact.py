"""Secrets never reach a log: redaction of names, values and zenoh errors."""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from typing import Any

log = logging.getLogger(__name__)

# -- secrets never reach a log ------------------------------------------------------------------
REDACTED = "***"
_SECRET_WORDS = ("password", "passwd", "passphrase", "pwd", "secret", "token", "credential")
_SECRET_NAME_RE = re.compile(
    r"(?:" + "|".join(_SECRET_WORDS) + r")|(?:^|[_.-])key$|^apikey$", re.IGNORECASE
)
_SECRET_ASSIGNMENT_RE = re.compile(
    r"""(?P<name>["']?[\w.-]*(?:"""
    + "|".join(_SECRET_WORDS)
    + r"""|(?<![\w])key|_key)["']?\s*[:=]\s*)"""
    r"""(?P<value>"(?:[^"\\]|\\.)*"|'[^']*'|[^\s,;{}\[\]]+)""",
    re.IGNORECASE,
)
_ERROR_VALUE_RE = re.compile(r"(invalid (?:type|value|length): [^`]*?)`[^`]*`")


def is_secret_name(name: str) -> bool:
    """Config names whose values are secrets: password, token, secret, ..._key, api key.

    ``key_exprs`` (zenoh access control) is not one: only a name *ending* in "key" is.
    """
    return bool(_SECRET_NAME_RE.search(name))


def redact_secrets(value: Any) -> Any:
    """A copy of a parsed config (mappings, lists) with every secret-named value replaced.

    A table under a secret-looking name (zenoh's ``usrpwd``) is searched, not hidden whole.

    Use it before logging any configuration (docs/reliability.md, "No secret in logs").
    """
    if isinstance(value, Mapping):
        return {
            k: (
                REDACTED
                if is_secret_name(str(k)) and not isinstance(v, Mapping | list | tuple)
                else redact_secrets(v)
            )
            for k, v in value.items()
        }
    if isinstance(value, list | tuple):
        return [redact_secrets(v) for v in value]
    return value


def redact_text(text: str) -> str:
    """Free text (an error message, a config excerpt) with secret-looking values replaced.

    zenoh quotes the offending source line of a bad JSON5 file and the offending value of a
    badly typed field in its errors; either may be a password.
    """
    text = _SECRET_ASSIGNMENT_RE.sub(lambda m: m.group("name") + REDACTED, text)
    return _ERROR_VALUE_RE.sub(lambda m: f"{m.group(1)}`{REDACTED}`", text)


def _zenoh_error_text(exc: BaseException) -> str:
    """zenoh errors carry Rust source locations; keep the sentence a user can act on.

    Values that may be secrets (see ``redact_text``) are replaced.
    """
    text = redact_text(str(exc))
    m = re.search(r'msg: "(.*?)"', text)
    if m:
        text = m.group(1)
    text = re.sub(r"\s+at /\S+?\.rs:\d+\.?", "", text)
    return " ".join(text.split())
