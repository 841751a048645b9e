"""Linear (P1) against quadratic (P2) tetrahedra: accuracy at equal degrees of freedom, and wall time.

Runs the three problems of :mod:`pliant.bench._p2` (elastica at α = 1 and 2 against Mattiasson's table,
the self-weight cantilever against Euler–Bernoulli, Cook's membrane) on a ladder of meshes for each
element order, prints one JSON line per solve, writes them to ``--out`` (JSON) and draws the convergence
figure (relative error against degrees of freedom, log–log, with the fitted slopes against the element
size h ∝ DOF^(-1/3)) to ``--figure``.

Errors in the figure and the slopes are against each problem's discretisation limit u*, Aitken's
extrapolation of its three finest P2 values; the offset of u* from the published value (model error: a 3D
solid is not an Euler–Bernoulli line; Cook's one-layer slab, clamped through its thickness, lies 0.03 %
below 23.96 and 0.06 % below a 2D plane-stress solve, see docs/tutorials/04_fem.md) is drawn as a dashed
line. Cook's membrane is read at the loaded edge's midpoint (48, 52), where the published 23.96 is
measured; P2 is within 0.3 % of it from 24² cells on (tests/test_fem_p2.py), the ladder's 32² is the
finest rung.

Usage (one core, the figures of the FEM tutorial; from a git worktree other than the one pliant is
installed from, prefix ``PYTHONPATH=.``: a script's own folder, not the working directory, heads sys.path):
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


def _limit(rows: list[dict]) -> float:
    """The discretisation limit of a problem: Aitken's extrapolation of its three finest P2 values."""
    v = [r["value"] for r in sorted((r for r in rows if r["order"] == 2), key=lambda r: r["dof"])[-3:]]
    d1, d2 = v[1] - v[0], v[2] - v[1]
    return v[2] + d2 * d2 / (d1 - d2) if d1 != d2 else v[2]


def _slope(rows: list[dict], limit: float) -> float:
    """Fitted p in |u_h − u*| ∝ h^p, h ∝ DOF^(-1/3), over the rows' finest three meshes."""
    r = sorted(rows, key=lambda r: r["dof"])[-3:]
    dof = np.array([x["dof"] for x in r], float)
    err = np.array([max(abs(x["value"] / limit - 1.0), 1e-12) for x in r])
    return float(-3.0 * np.polyfit(np.log(dof), np.log(err), 1)[0])


def report(rows: list[dict], figure: str | None) -> dict:
    """Limits, errors to them and fitted slopes per problem and order; the figure when ``figure``."""
    names = ["elastica_alpha1", "elastica_alpha2", "self_weight_cantilever", "cook_membrane"]
    summary: dict = {}
    for name in names:
        sel = [r for r in rows if r["benchmark"] == name]
        if not sel:
            continue
        limit = _limit(sel)
        summary[f"{name}_limit"] = limit
        summary[f"{name}_limit_vs_reference"] = limit / sel[0]["reference"] - 1.0
        for r in sel:
            r["rel_error_to_limit"] = r["value"] / limit - 1.0
        for order in (1, 2):
            part = [r for r in sel if r["order"] == order]
            if len(part) >= 3:
                summary[f"{name}_P{order}_slope"] = _slope(part, limit)
    if figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 4))
        for ax, name in zip(axes, names, strict=True):
            limit = summary[f"{name}_limit"]
            for order, style in ((1, "o-"), (2, "s-")):
                sel = sorted(
                    (r for r in rows if r["benchmark"] == name and r["order"] == order),
                    key=lambda r: r["dof"],
                )
                err = [max(abs(r["value"] / limit - 1.0), 1e-6) for r in sel]
                slope = summary.get(f"{name}_P{order}_slope")
                label = f"P{order}" + ("" if slope is None else f", slope {slope:.1f} in h")
                ax.loglog([r["dof"] for r in sel], err, style, label=label)
            off = abs(summary[f"{name}_limit_vs_reference"])
            ax.axhline(off, color="gray", ls="--", lw=1, label=f"limit vs published: {100 * off:.2f} %")
            ax.set_title(name.replace("_", " "))
            ax.set_xlabel("degrees of freedom")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
        axes[0].set_ylabel("|u − u*| / u*  (u*: extrapolated limit)")
        fig.tight_layout()
        fig.savefig(figure, dpi=100)
    return summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the two smallest meshes of each ladder")
    ap.add_argument("--out", default=None, help="JSON file for the rows")
    ap.add_argument("--figure", default=None, help="PNG file for the convergence figure")
    ap.add_argument("--from-json", default=None, help="redraw from the rows of an earlier --out file")
    args = ap.parse_args()
    if args.from_json:
        with open(args.from_json) as f:
            rows = json.load(f)["rows"]
        print(json.dumps(report(rows, args.figure)))
        return

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

    summary = report(rows, args.figure)
    print(json.dumps(summary))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"rows": rows, "summary": summary}, f, indent=1)


if __name__ == "__main__":
    main()
