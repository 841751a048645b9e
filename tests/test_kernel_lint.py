"""Kernel parameter discipline (../shared/STYLE.md, B3), checked on every ``@wp.kernel`` in pliant.

The rule, as STYLE.md states it:

    **Parameter order and suffixes** follow MuJoCo Warp: Model parameters have no suffix, state and
    scratch parameters end in ``_in`` / ``_out``, bracket array syntax, no defaults or kwargs.

with the groups in the order of its example: ``# Model:`` (no suffix), ``# State in:`` (``_in``), ``# Out:``
(``_out``). What ``ast`` can decide without running the kernel, and so what this lint checks:

1. ``written``: a parameter the kernel writes (``a[i] = ...``, ``a[i] += ...``, ``a[i][k] = ...``, or the
   first argument of ``wp.atomic_*``) ends in ``_out`` (``_io`` where it is updated in place, as pliant's
   XPBD and contact kernels do; a bare ``out`` is the suffix alone); one ending so is written, or at least
   handed to a ``@wp.func`` that may write it.
2. ``read-only in``: a parameter ending in ``_in`` is never written.
3. ``order``: array parameters come in the groups unsuffixed, then ``_in``, then ``_out``/``_io``. Scalars
   (``dt``, ``scale``, ``mode``) are launch settings, in no group.
4. ``default``: no parameter has a default value.

A read-only state array without ``_in`` cannot be told from a Model array by its syntax, so it is not
flagged; nor is the bracket array syntax, which no kernel of pliant uses yet (all use ``wp.array(dtype=.)``).

``ALLOWED`` lists the kernels that broke the rule when the lint was written (56 of 144, issue 26), keyed
``subpackage:kernel`` so that a file moving inside its subpackage keeps its entry. A new violation fails,
and so does an allowed kernel that now follows the rule: remove it, so the list only shrinks.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "pliant"
ATOMICS = ("atomic_add", "atomic_sub", "atomic_min", "atomic_max", "atomic_cas", "atomic_exch")

#: Kernels that broke the rule when the lint was written (issue 26), to be fixed, never added to.
ALLOWED: set[str] = set()


def _is_kernel(node: ast.AST) -> bool:
    if not isinstance(node, ast.FunctionDef):
        return False
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if ast.unparse(target) in ("wp.kernel", "warp.kernel"):
            return True
    return False


def _root_name(node: ast.expr) -> str | None:
    """The variable a subscript chain starts from (``a`` of ``a[i][k]`` or ``a[i, j]``)."""
    while isinstance(node, ast.Subscript | ast.Attribute):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _targets(t: ast.expr) -> list[ast.expr]:
    """The single targets of an assignment target (``a[i], b[i] = ...`` has two)."""
    if isinstance(t, ast.Tuple | ast.List):
        return [x for e in t.elts for x in _targets(e)]
    return [t]


def _written(kernel: ast.FunctionDef) -> set[str]:
    """Names of the kernel's parameters that its body writes (the array indexed on the left of ``=``, not
    the arrays read in its index: ``rank[sorted_vals[i]] = i`` writes ``rank`` only)."""
    out: set[str] = set()
    for node in ast.walk(kernel):
        targets: list[ast.expr] = []
        if isinstance(node, ast.Assign):
            targets = [x for t in node.targets for x in _targets(t)]
        elif isinstance(node, ast.AugAssign | ast.AnnAssign):
            targets = [node.target]
        elif isinstance(node, ast.Call) and node.args:
            name = ast.unparse(node.func).rsplit(".", 1)[-1]
            if name in ATOMICS:
                targets = [ast.Subscript(value=node.args[0], slice=ast.Constant(0))]
        for t in targets:
            if isinstance(t, ast.Subscript) and (name := _root_name(t)):
                out.add(name)
    params = {a.arg for a in kernel.args.args}
    return out & params


def _passed(kernel: ast.FunctionDef) -> set[str]:
    """Names passed whole to a call (a ``@wp.func`` may write them; the lint cannot see inside)."""
    return {
        a.id for n in ast.walk(kernel) if isinstance(n, ast.Call) for a in n.args if isinstance(a, ast.Name)
    }


def _group(name: str) -> int:
    """0: Model (no suffix), 1: state in (``_in``), 2: out (``_out``, ``out``, or ``_io`` for in place)."""
    if name == "out" or name.endswith(("_out", "_io")):
        return 2
    return 1 if name.endswith("_in") else 0


def _is_array(arg: ast.arg) -> bool:
    return arg.annotation is not None and ast.unparse(arg.annotation).startswith(("wp.array", "warp.array"))


def kernel_violations(source: str) -> dict[str, list[str]]:
    """Kernel name → its violations of the rule, for every ``@wp.kernel`` in ``source``."""
    found: dict[str, list[str]] = {}
    for node in ast.walk(ast.parse(source)):
        if not _is_kernel(node):
            continue
        assert isinstance(node, ast.FunctionDef)
        names = [a.arg for a in node.args.args]
        written, passed = _written(node), _passed(node)
        bad = [f"written: {n} is written, so ends in _out" for n in names if n in written and _group(n) != 2]
        bad += [
            f"written: {n} ends in _out but is only read"
            for n in names
            if _group(n) == 2 and n not in written and n not in passed
        ]
        bad += [
            f"read-only in: {n} ends in _in but is written" for n in names if _group(n) == 1 and n in written
        ]
        arrays = [a.arg for a in node.args.args if _is_array(a)]
        groups = [_group(n) for n in arrays]
        if groups != sorted(groups):
            bad.append("order: arrays are not grouped unsuffixed, then _in, then _out: " + ", ".join(arrays))
        if node.args.defaults or node.args.kw_defaults or node.args.kwonlyargs:
            bad.append("default: a parameter has a default value or is keyword-only")
        if bad:
            found[node.name] = bad
    return found


def all_violations() -> dict[str, list[str]]:
    """``subpackage:kernel`` → violations, over every module of pliant."""
    found: dict[str, list[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        sub = rel.parts[0].removesuffix(".py") if len(rel.parts) > 1 else rel.stem
        for kernel, bad in kernel_violations(path.read_text(encoding="utf-8")).items():
            found.setdefault(f"{sub}:{kernel}", []).extend(f"{rel}: {b}" for b in bad)
    return found


def test_no_new_kernel_violates_the_parameter_rule():
    """Every @wp.kernel outside ALLOWED follows the suffix, order and no-default rule."""
    new = {k: v for k, v in all_violations().items() if k not in ALLOWED}
    assert not new, "kernels breaking STYLE.md B3 (rename the parameters):\n" + "\n".join(
        f"{k}: {b}" for k, v in new.items() for b in v
    )


def test_allowed_violators_still_violate():
    """Each allowed kernel still breaks the rule (a fixed one leaves ALLOWED, so the list only shrinks)."""
    fixed = ALLOWED - set(all_violations())
    assert not fixed, f"these kernels now follow the rule; remove them from ALLOWED: {sorted(fixed)}"


def test_the_lint_sees_a_violating_kernel():
    """The checker is not vacuous: a synthetic kernel breaking each clause is reported, a good one is not."""
    bad = """
@wp.kernel(enable_backward=False)
def _bad(x_out: wp.array(dtype=float), k: wp.array(dtype=float), q_in: wp.array(dtype=float),
         grad: wp.array(dtype=float), scale: float = 1.0):
    i = wp.tid()
    q_in[i] = 0.0
    wp.atomic_add(grad, i, k[i] * scale)

@wp.kernel
def _good(k: wp.array(dtype=float), q_in: wp.array(dtype=float), grad_out: wp.array2d(dtype=float),
          p_io: wp.array(dtype=float), dt: float):
    i = wp.tid()
    grad_out[i, 0] += k[i] * q_in[i]
    grad_out[k[i], 1] = q_in[i]  # k is read (an index), not written
    wp.atomic_sub(p_io, i, dt)

@wp.func
def _not_a_kernel(x: float):
    return x
"""
    found = kernel_violations(bad)
    assert set(found) == {"_bad"}, found
    text = "\n".join(found["_bad"])
    assert "written: grad is written" in text
    assert "x_out ends in _out but is only read" in text
    assert "q_in ends in _in but is written" in text
    assert "order:" in text and "default:" in text
