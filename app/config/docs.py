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
        if name == "boundary":
            out.append("One entry per domain face (`x-`, `x+`, `y-`, `y+`, `z-`, `z+`, or `bottom`, `top`), each an "
                       "inline table of the keys below, e.g. `bottom = { kind = \"velocity_inlet\", velocity = "
                       "[0.0, 0.0, 0.5] }`. Faces not listed are no-slip walls. Override one key with "
                       "`--set boundary.bottom.velocity=[0,0,0.8]`.\n")
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
