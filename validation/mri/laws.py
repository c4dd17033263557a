"""What the four drag laws of the study do differently, for the poppy seeds: the exchange coefficient beta of
each law against the gas fraction at two slips (the superficial 0.30 m/s and 0.45 m/s over eps), relative to
Koch & Hill, and the bed's terminal state figures each law implies.

    python3 validation/mri/laws.py validation/mri      # writes laws.md and laws.png there

Grains of the Sauter diameter 1.057 mm (the classes by mass), air at 1.2 kg/m^3 and 1.8e-5 Pa s. Imports
app.sim.drag (Taichi): a script, not an analysis.
"""
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
from app.sim import drag  # noqa: E402

LAWS = ("koch_hill", "di_felice", "gidaspow", "beetstra")
D, RHO, MU = 1.057e-3, 1.2, 1.8e-5


def main(out: str) -> int:
    out = pathlib.Path(out)
    eps = np.array([0.40, 0.45, 0.50, 0.60, 0.70, 0.80, 0.90, 0.97])
    lines = ["# The four drag laws for the poppy seeds (d32 = 1.057 mm, air)\n",
             "beta / beta_Koch&Hill at the slip U / eps (U superficial); Re = eps rho d |w| / mu = rho d U / mu.\n"]
    for u in (0.30, 0.45):
        lines.append(f"\nU = {u} m/s (Re = {RHO * D * u / MU:.1f})\n")
        lines.append("| eps | " + " | ".join(LAWS) + " | Koch & Hill beta [kg/m^3/s] |")
        lines.append("|---|" + "---|" * (len(LAWS) + 1))
        ref = drag.beta("koch_hill", eps, u / eps, D, RHO, MU)
        for k, e in enumerate(eps):
            row = [float(drag.beta(law, e, u / e, D, RHO, MU)) / ref[k] for law in LAWS]
            lines.append(f"| {e:.2f} | " + " | ".join(f"{x:.3f}" for x in row) + f" | {ref[k]:.4g} |")
    (out / "laws.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = np.linspace(0.38, 0.99, 200)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for law in LAWS:
        b = drag.beta(law, e, 0.45 / e, D, RHO, MU)
        ax[0].semilogy(e, b, label=law)
        ax[1].plot(e, b / drag.beta("koch_hill", e, 0.45 / e, D, RHO, MU), label=law)
    ax[0].set(xlabel="gas fraction", ylabel="beta [kg m^-3 s^-1]", title="U = 0.45 m/s, d = 1.057 mm")
    ax[1].set(xlabel="gas fraction", ylabel="beta / Koch & Hill", ylim=(0, 2.5))
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "laws.png", dpi=100)
    print((out / "laws.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "."))
