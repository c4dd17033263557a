"""Markdown reference of every preset key (unit, default, meaning), generated from the schema.

    python -m app.config.docs   # prints the tables that README.md embeds
"""
from __future__ import annotations

import dataclasses

from .loader import SECTION_TYPES


def reference() -> str:
    out = []
    for name, cls in SECTION_TYPES.items():
        doc = "" if name not in ("run", "domain") else " (required)"
        out.append(f"#### `[{name}]`{doc}\n")
        out.append("| key | unit | default | meaning |\n|---|---|---|---|")
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                default = "—" if f.default is None else f"`{f.default!r}`" if not isinstance(f.default, str) else f'`"{f.default}"`'
            elif f.default_factory is not dataclasses.MISSING:
                default = f"`{f.default_factory()!r}`"
            else:
                default = "required"
            meta = f.metadata
            choices = f" ({' / '.join(meta['choices'])})" if meta.get("choices") else ""
            out.append(f"| `{f.name}` | {meta.get('unit', '-')} | {default} | {meta.get('doc', '')}{choices} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    print(reference())
