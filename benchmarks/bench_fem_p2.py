"""Linear (P1) against quadratic (P2) tetrahedra: accuracy at equal degrees of freedom, and wall time.

Runs the three problems of :mod:`pliant.bench._p2` (elastica at α = 1 and 2 against Mattiasson's table,
the self-weight cantilever against Euler–Bernoulli, Cook's membrane) on a ladder of meshes for each
element order, prints one JSON line per solve, writes them to ``--out`` (JSON) and draws the convergence
figure (relative error against degrees of freedom, log–log, with the fitted slopes against the element
size h ∝ DOF^(-1/3)) to ``--figure``.

Cook's membrane's error is measured against the P2 value extrapolated from its two finest meshes (see
docs/tutorials/04_fem.md: the plane-stress 23.96 of the literature is not this problem's limit).

Usage (one core, the figures of the FEM tutorial):
    taskset -c 1 .venv/bin/python benchmarks/bench_fem_p2.py --out docs/figures/fem_p2.json \\
        --figure docs/figures/fem_p2_convergence.png
    taskset -c 1 .venv/bin/python benchmarks/bench_fem_p2.py --quick
"""

from __future__ import annotations

import argparse
import json

import numpy as np

# (P1 cells, P2 cells) ladders with about equal DOF per rung: P2 on n cells has the nodes of P1 on 2n.
ELASTICA = {1: [(40, 2, 2), (80, 4, 4), (120, 6, 6)], 2: [(10, 1, 1), (20, 1, 1), (40, 2, 2)]}
CANTILEVER = {1: [(40, 2, 2), (80, 4, 4), (160, 8, 8)], 2: [(10, 1, 1), (20, 1, 1), (40, 2, 2), (80, 4, 4)]}
COOK = {1: [8, 16, 32, 64], 2: [2, 4, 8, 16, 32]}


def _slope(rows: list[dict], reference: float) -> float:
    """Fitted p in |error| ∝ h^p, h ∝ DOF^(-1/3), over the rows' finest three meshes."""
    r = sorted(rows, key=lambda r: r["dof"])[-3:]
    dof = np.array([x["dof"] for x in r], float)
    err = np.array([abs(x["value"] / reference - 1.0) for x in r])
    return float(-3.0 * np.polyfit(np.log(dof), np.log(err), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the two smallest meshes of each ladder")
    ap.add_argument("--out", default=None, help="JSON file for the rows")
    ap.add_argument("--figure", default=None, help="PNG file for the convergence figure")
    args = ap.parse_args()

    import warp as wp

    wp.config.quiet = True
    from pliant.bench._p2 import cook_membrane, elastica, self_weight_cantilever

    def ladder(d: dict, order: int) -> list:
        return d[order][:2] if args.quick else d[order]

    elastica((4, 1, 1), order=2)  # warm-up: compile the kernels before timing
    elastica((4, 1, 1), order=1)
    rows: list[dict] = []

    def run(row: dict) -> None:
        rows.append(row)
        print(json.dumps(row), flush=True)

    for order in (1, 2):
        for alpha in (1.0, 2.0):
            for cells in ladder(ELASTICA, order):
                run(elastica(cells, order=order, alpha=alpha, load_steps=4 if alpha == 1.0 else 8))
        for cells in ladder(CANTILEVER, order):
            run(self_weight_cantilever(cells, order=order))
        for n in ladder(COOK, order):
            run(cook_membrane(n, order=order))

    # Cook's limit: Richardson from the two finest P2 meshes (rate 2 in h, the corner singularity's).
    p2 = sorted(
        (r for r in rows if r["benchmark"] == "cook_membrane" and r["order"] == 2), key=lambda r: r["dof"]
    )
    cook_limit = p2[-1]["value"] + (p2[-1]["value"] - p2[-2]["value"]) / 3.0
    for r in rows:
        if r["benchmark"] == "cook_membrane":
            r["extrapolated_limit"] = cook_limit
            r["rel_error_to_limit"] = r["value"] / cook_limit - 1.0

    summary = {}
    for name in sorted({r["benchmark"] for r in rows}):
        for order in (1, 2):
            sel = [r for r in rows if r["benchmark"] == name and r["order"] == order]
            ref = cook_limit if name == "cook_membrane" else sel[0]["reference"]
            if len(sel) >= 3:
                summary[f"{name}_P{order}_slope"] = _slope(sel, ref)
    print(json.dumps({"cook_limit": cook_limit, **summary}))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"rows": rows, "cook_limit": cook_limit, "slopes": summary}, f, indent=1)
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        names = ["elastica_alpha1", "elastica_alpha2", "self_weight_cantilever", "cook_membrane"]
        fig, axes = plt.subplots(1, 4, figsize=(16, 4))
        for ax, name in zip(axes, names, strict=True):
            for order, style in ((1, "o-"), (2, "s-")):
                sel = sorted(
                    (r for r in rows if r["benchmark"] == name and r["order"] == order),
                    key=lambda r: r["dof"],
                )
                ref = cook_limit if name == "cook_membrane" else sel[0]["reference"]
                err = [max(abs(r["value"] / ref - 1.0), 1e-6) for r in sel]
                slope = summary.get(f"{name}_P{order}_slope")
                label = f"P{order}" + ("" if slope is None else f" (slope {slope:.1f} in h)")
                ax.loglog([r["dof"] for r in sel], err, style, label=label)
            ax.set_title(name.replace("_", " "))
            ax.set_xlabel("degrees of freedom")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        axes[0].set_ylabel("relative error")
        fig.tight_layout()
        fig.savefig(args.figure, dpi=110)


if __name__ == "__main__":
    main()
