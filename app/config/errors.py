"""The preset error every config module raises, and where a key sits in its file (no other imports:
loader, rules and derived all use it, so none of them needs another)."""
from __future__ import annotations

import re


class ConfigError(Exception):
    """A preset problem: ``str(err)`` is the full user-facing message."""

    def __init__(self, message: str, file: str = "", key: str = "", line: int | None = None, hint: str = ""):
        self.file, self.key, self.line, self.hint, self.message = file, key, line, hint, message
        where = file or ("" if key.startswith("-") else "<preset>")  # a command-line flag needs no file
        if line:
            where += f":{line}"
        text = f"{where + ': ' if where else ''}{key + ': ' if key else ''}{message}"
        if hint:
            text += f"\n  hint: {hint}"
        super().__init__(text)


# ---------------------------------------------------------------------------- locating keys

def find_line(text: str, section: str, key: str | None) -> int | None:
    """Best-effort line number of ``[section] key = ...`` (tomllib gives no positions)."""
    if not text:
        return None
    lines = text.splitlines()
    in_section = False
    header = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-]+)\s*\]")
    for no, line in enumerate(lines, 1):
        m = header.match(line)
        if m:
            in_section = m.group(1) == section
            if in_section and key is None:
                return no
            continue
        if in_section and key is not None and re.match(rf"^\s*{re.escape(key)}\s*=", line):
            return no
        # dotted keys at top level: section.key = ...
        if key is not None and re.match(rf"^\s*{re.escape(section)}\.{re.escape(key)}\s*=", line):
            return no
    return None
