"""The rCFD mixing curve against the full runs', per jump, from `fbed rcfd validate` reports on the same runs.

    python3 validation/rcfd/jump_curves.py NAME=VALIDATION_JSON [NAME=VALIDATION_JSON ...] [--json OUT]

Each VALIDATION_JSON is the validation.json of one `fbed rcfd validate ... --jump J` on the same database and
continuations (the runs are reused, so only the jump differs). Per jump: the index change per jump, the rCFD
ensemble mean's signed mean error and RMS error against the full runs' mean over the whole horizon (cell index
and Lacey's index), the full runs' own spread, and both curves at a few times. Prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

TIMES = (0.5, 1.0, 1.5, 2.0, 3.0)  # [s] after the database's end


def curves(path: pathlib.Path) -> dict:
    d = json.loads(path.read_text())
    full = d["full_curves"]
    t = np.asarray(full["t"])
    out = {"jump": d["jump"], "jump_dM_mean": d["jump_dM_mean"], "t": t}
    for key, rkey in (("M", "rcfd_mean_curve"), ("L", "rcfd_mean_lacey")):
        f = np.asarray(full[key])
        r = np.asarray(d[rkey])
        out[key] = {"full": f.mean(0), "rcfd": r, "mean_error": float(np.mean(r - f.mean(0))),
                    "rms_error": float(np.sqrt(np.mean((r - f.mean(0)) ** 2))),
                    "full_spread": float(f.std(0, ddof=1).mean())}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("reports", nargs="+", help="NAME=path/to/validation.json")
    ap.add_argument("--json", help="also write the figures here")
    a = ap.parse_args(argv)
    rows = {}
    for item in a.reports:
        name, _, path = item.partition("=")
        rows[name] = curves(pathlib.Path(path))
    print("| jump | index change per jump | cell index: mean error, RMS (full runs' spread) | Lacey: mean error, RMS "
          "(spread) | " + " | ".join(f"M, L at {t:g} s (full)" for t in TIMES) + " |")
    print("|---" * (4 + len(TIMES)) + "|")
    for name, c in rows.items():
        at = []
        for t in TIMES:
            if t > c["t"][-1] + 1e-9:
                at.append("")
                continue
            i = int(np.argmin(np.abs(c["t"] - t)))
            at.append(f"{c['M']['rcfd'][i]:.3f}, {c['L']['rcfd'][i]:.3f} ({c['M']['full'][i]:.3f}, "
                      f"{c['L']['full'][i]:.3f})")
        M, L = c["M"], c["L"]
        print(f"| {name} | {c['jump_dM_mean']:.4f} | {M['mean_error']:+.3f}, {M['rms_error']:.3f} "
              f"({M['full_spread']:.3f}) | {L['mean_error']:+.3f}, {L['rms_error']:.3f} ({L['full_spread']:.3f}) | "
              + " | ".join(at) + " |")
    if a.json:
        keep = {n: {"jump": c["jump"], "jump_dM_mean": c["jump_dM_mean"],
                    **{k: {q: c[k][q] for q in ("mean_error", "rms_error", "full_spread")} for k in ("M", "L")}}
                for n, c in rows.items()}
        pathlib.Path(a.json).write_text(json.dumps(keep, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
