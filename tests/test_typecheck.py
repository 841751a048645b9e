"""tests/typecheck.py keeps mypy's errors in host code and drops only those inside Warp kernels/functions."""

from __future__ import annotations

import typecheck

SOURCE = """import warp as wp

@wp.kernel(enable_backward=False)
def k(x: wp.array(dtype=float)):
    i, j = wp.tid()

@wp.func
def f(a: float):
    return a

def host(x: int) -> str:
    return x
"""


def test_errors_inside_kernels_are_dropped_and_host_errors_kept(tmp_path):
    """Errors on a kernel's decorator, signature or body and a @wp.func's are dropped; a host one is kept."""
    path = tmp_path / "mod.py"
    path.write_text(SOURCE)
    report = "\n".join(
        [
            f"{path}:3: error: decorator  [misc]",
            f"{path}:4: error: Invalid type comment or annotation  [valid-type]",
            f"{path}:4: note: Cannot use a function call in a type annotation",
            f'{path}:5: error: "int" object is not iterable  [misc]',
            f"{path}:9: error: in a func  [misc]",
            f'{path}:12: error: Incompatible return value type (got "int", expected "str")  [return-value]',
            f"{path}:12: note: a note of the kept error",
        ]
    )
    kept, dropped = typecheck.host_errors(report)
    assert dropped == 4, kept
    assert kept == [
        f'{path}:12: error: Incompatible return value type (got "int", expected "str")  [return-value]',
        f"{path}:12: note: a note of the kept error",
    ]


#: Plain-Python ``Any`` annotations left in pliant/ (``python tests/typecheck.py --any`` lists them). Issue 26
#: item 4 took it from 396 to this; it may only go down. Where ``Any`` stays, the type truly varies or no
#: type exists to name:
#:
#: - objects of untyped third-party packages (viser in ``live/_server.py`` and ``render/_viewer.py``, torch in
#:   ``diff/_torch.py``, matplotlib, meshio, imageio-ffmpeg, pxr, threadpoolctl): with no stubs
#:   (``ignore_missing_imports`` in pyproject.toml) mypy reads any name of theirs as ``Any`` anyway;
#: - raw input before validation: pydantic ``mode="before"`` validators and TOML values
#:   (``scene/_schema.py``, ``scene/_overrides.py``, ``TetOrder._order_is_a_whole_number``);
#: - Warp objects used as values: a ``@wp.func`` passed to a kernel factory (``constraints/_factory.py``,
#:   ``_generic.py``, ``energies/_materials.py``, ``make_hessian``), which mypy sees through Warp's untyped
#:   decorator, and Warp type objects read by duck typing (``_prebuild._type_json``,
#:   ``energies/_fem_math.declare_overloads``);
#: - pass-through wrappers of Warp internals (``_prebuild``'s ``build_cpu`` / ``Module.load``,
#:   ``_warp._runtime``, whose module moved between Warp versions);
#: - dynamic lookups whose value type depends on the key (``ImplicitOptions.__getattr__``,
#:   ``RegistryView.__getitem__``) and functions duck-typed over every object or example kind
#:   (``scene/_size._object_counts`` and, since issue 41's bounded size estimate, its ``_bounded_counts``
#:   and ``_driver``; ``fit/_models._spacing``, ``examples/_common.main``);
#: - ``compliance`` scalar-or-per-constraint in the constraint constructors (``npt.ArrayLike`` there needs
#:   the ``float(compliance)`` branches rewritten; left while those files' kernels are being reworked).
#: 107 until 2026-11-28; 117 since: issue 41 added the two size-estimate functions above,
#: ``fit/_cmaes._replay`` (an untyped ``cma.CMAEvolutionStrategy``), and seven viser objects of the live
#: server's token check, its scripted clients and its tab events (``render/_viewer.require_token``,
#: ``live/_probe.py``, ``live/_server.py``: untyped third-party, as above).
MAX_PLAIN_ANY = 117

COUNTED = """from typing import Any, Optional
import typing
import warp as wp

@wp.kernel
def k(x: wp.array(dtype=Any), s: Any):
    pass

@wp.func
def f(a: Any) -> Any:
    return a

def host(a: Any, b: Any | None, c: Optional[Any], d: "Any", e: typing.Any, *args: Any, **kw: Any) -> Any:
    x: Any = 1
    y: dict[str, Any] = {}
    z: list[Any] = []
    return x

class C:
    attr: Any = None

    def m(self, g: dict[str, Any], h: int) -> Any | None:
        return None
"""


def test_plain_any_counter(tmp_path):
    """The counter finds Any alone (also ``Any | None``, ``Optional[Any]``, ``"Any"``, ``typing.Any``) in
    parameters, returns and annotated assignments; it skips Warp kernels and functions, containers of Any
    and ``*args`` / ``**kwargs``."""
    path = tmp_path / "mod.py"
    path.write_text(COUNTED)
    found = [hit.split(": ", 1)[1] for hit in typecheck.plain_any(path)]
    assert found == [
        "host(a: Any)",
        "host(b: Any)",
        "host(c: Any)",
        "host(d: Any)",
        "host(e: Any)",
        "host() -> Any",
        "x: Any",
        "attr: Any",
        "m() -> Any",
    ]


def test_plain_any_only_goes_down():
    """pliant/ has at most MAX_PLAIN_ANY plain-Python Any annotations, and exactly that many (lower it when
    you remove some, so that the count cannot creep back up)."""
    hits = typecheck.all_plain_any()
    listing = "\n".join(hits)
    assert len(hits) <= MAX_PLAIN_ANY, (
        f"{len(hits)} plain-Python Any annotations in pliant/, more than MAX_PLAIN_ANY = {MAX_PLAIN_ANY}. "
        "Name the real type (pl.Model, State, Solver, SceneConfig, wp.array, np.ndarray, npt.ArrayLike, a "
        "Protocol for duck-typed arguments, `object` when anything is accepted and only passed on); import "
        "it under `if TYPE_CHECKING:` to avoid a cycle. Keep Any only where the type truly varies (see "
        f"this module's list).\n{listing}"
    )
    assert len(hits) == MAX_PLAIN_ANY, (
        f"pliant/ now has {len(hits)} plain-Python Any annotations: lower MAX_PLAIN_ANY in "
        f"tests/test_typecheck.py to {len(hits)} so that the count only goes down"
    )
