"""The generated module of an actuator family: its equations with every parameter an entry of a
vector ``p``, compiled by numba and cached on disk.

**One module per family, not per effect selection.** The module calls every term a rig of the
family can have (the registry's, imported and wrapped by ``numba.njit`` as they are: no second copy
of an equation). Which of them act is data in ``p``:

* an effect that changes the chain (the lag state, a duty transform, a drive map, the dynamic
  armature) is switched by a flag entry of ``p`` tested at run time, which selects exactly the
  code the rig's own :class:`~aeropend_sim.components.assembly.Assembly` would run;
* an effect whose terms all sit in a summed slot (:data:`aeropend_sim.components.base.SUM_SLOTS`:
  frictions, drag, back-EMF, end stops) stays in the sum, and its absent parameter values make it
  add an exact 0.0 (:func:`switched_by_value`; ``test_compiled.py`` checks each such term), except
  that one whose terms call a libm function (:data:`LIBM`: a Coulomb friction's tanh, its Stribeck
  exp) has a flag too, and adds 0.0 without evaluating them where it is off
  (:func:`skipped_when_off`). Evaluated at their absent values, the two Coulomb frictions took
  about 40 % of a fit replay of a rig without them. Paired in one process (2026-11-27, three
  runs, time per RK4 sub-step new/old, θ the same bit for bit): 0.55-0.62× on the independent
  benchmark's nominal rig, 0.71-0.76× on ``etchepareborda_rig``, 0.85-0.94× on ``thesis_rig``,
  and 1.04-1.18× on the rig with every effect on, which pays the two branches (a flag on every
  summed effect cost it 1.17-1.21×). Skipping changes no value (at most the sign of an exact zero
  sum).

So a rig compiles once per machine whatever its switches (one module per family, and one more
per set of effect states a rig of it has: an effect with a state of its own, ``motor_heating``,
lengthens the state the kernels integrate), and a new parameter set or effect selection never
recompiles. The source is written by the same
:func:`aeropend_sim.components.assembly.chain_source` as the LSODA right-hand side, followed by
the integrator text of :mod:`.kernels`.

**Disk cache.** The module is written to :func:`cache_dir` under a name that hashes its text
(which quotes a hash of every source file it imports from, and the numba version), then
imported, so numba's ``cache=True`` applies: the first process on a machine compiles (seconds per
kernel), later processes load the machine code (≈ 0.2 s).
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numba
import numpy as np

from aeropend_sim.compiled import kernels, xp_numba
from aeropend_sim.components import registry
from aeropend_sim.components.assembly import Assembly, AssemblyError, Wiring, chain_source, rates, state_args
from aeropend_sim.components.base import SUM_SLOTS, Effect, Term
from aeropend_sim.components.states import N_CHAIN

#: Environment variable that moves the cache folder (default ``$XDG_CACHE_HOME/aeropend`` or
#: ``~/.cache/aeropend``).
CACHE_ENV = "AEROPEND_CACHE_DIR"

#: The line of :mod:`.kernels` after which its text goes into the generated modules.
KERNELS_MARKER = "# ---- generated modules include the text below this line ----"



def switched_by_value(effect: Effect) -> bool:
    """Whether an effect's absent parameter values alone switch it off in the compiled model.

    True when every term sits in a summed slot and the effect has no mode: off, its parameters
    hold their absent values and each term adds an exact 0.0 (a flag, :func:`skipped_when_off`,
    then only saves evaluating them). False for effects that change the chain (a run-time flag
    switches them, :class:`Layout`); an effect without terms (input delay, thrust exponent,
    sensors) is data only: True.
    """
    return effect.modes is None and all(t.slot in SUM_SLOTS for t in effect.terms)


#: Functions of the ``xp`` namespace that are a libm call each (tens of ns, against about one for
#: an add): a term calling one is worth a branch that skips it where its effect is off.
LIBM = frozenset({"tanh", "exp", "sin", "cos", "sqrt", "power"})


def skipped_when_off(effect: Effect) -> bool:
    """Whether a summed-slot effect gets a flag that skips its terms where it is off (module doc):
    one of its term functions calls a :data:`LIBM` function of ``xp`` (read from the names its
    code refers to; a helper it calls is not looked into, and such an effect stays switched by
    its absent values, which is as exact)."""
    return switched_by_value(effect) and any(LIBM & set(t.fn.__code__.co_names) for t in effect.terms)


@dataclass(frozen=True)
class Layout:
    """The parameter vector ``p`` of a family's compiled model.

    Attributes
    ----------
    family : str
    keys : tuple of str
        ``p[i]`` is the (effective) value of ``keys[i]``: every parameter of the family, in the
        registry's order.
    flags : tuple of str
        ``p[len(keys) + j]`` is 1.0 where the effect ``flags[j]`` acts, 0.0 where not: the effects
        that change the chain and those :func:`skipped_when_off` (module doc).
    """

    family: str
    keys: tuple[str, ...]
    flags: tuple[str, ...]

    @property
    def size(self) -> int:
        """Length of ``p``."""
        return len(self.keys) + len(self.flags)

    def index(self, key: str) -> int:
        """Position of parameter ``key`` in ``p``.

        Raises
        ------
        KeyError
            If the family has no such parameter.
        """
        return self.keys.index(key) if key in self.keys else _missing(key, self.family)

    def flag_index(self, effect: str) -> int:
        """Position of the flag of ``effect`` in ``p``."""
        return len(self.keys) + self.flags.index(effect)

    def vector(self, assembly: Assembly) -> np.ndarray:
        """``p`` of an assembled rig: its effective parameter values and which flagged effects act."""
        flags = [1.0 if assembly.has(name) else 0.0 for name in self.flags]
        return np.array([float(assembly.values[k]) for k in self.keys] + flags)


def _missing(key: str, family: str) -> int:
    raise KeyError(f"the {family} family has no parameter {key!r}")


@registry.derived  # a part registered later may change it
def layout(family: str) -> Layout:
    """The :class:`Layout` of ``family``'s compiled model."""
    return _layout(registry.resolved(family))


def _layout(built: registry.Resolved) -> Layout:
    flags = tuple(e.name for e in built.effects if not switched_by_value(e) or skipped_when_off(e))
    return Layout(built.family.name, tuple(built.params), flags)


def _wiring(built: registry.Resolved, lay: Layout, fn: Any, states: tuple[str, ...]) -> Wiring:
    """Every term a rig of the family with the effect states ``states`` can have, flagged effects
    behind their flags, parameters as entries of ``p`` (a term that reads or drives a state not in
    ``states`` belongs to an effect that is off on such a rig: left out)."""
    parts = sorted((*built.parts, *built.effects), key=lambda p: (p.order, p.name))
    slots: dict[str, list[tuple[Term, str | None]]] = {}
    for part in parts:
        flagged = isinstance(part, Effect) and part.name in lay.flags
        guard = f"p[{lay.flag_index(part.name)}] != 0.0" if flagged else None
        for term in part.terms:
            if set(term.states) <= set(states) and (term.state is None or term.state in states):
                slots.setdefault(term.slot, []).append((term, guard))
    ordered = {k: tuple(sorted(v, key=lambda tg: tg[0].order)) for k, v in slots.items()}
    fam = built.family
    armature = "armature" not in fam.lacks
    lag = ordered.get("lag", ())
    dynamic = (f"p[{lay.flag_index('armature_inductance')}] != 0.0"
               if armature and "armature_inductance" in lay.flags else False)
    position = {k.partition(".")[2]: i for i, k in enumerate(lay.keys)}
    return Wiring(armature=armature, drive=fam.drive, slots=ordered,
                  lag=(lag[-1][1] or True) if lag else False, dynamic_current=dynamic,
                  arg=lambda name: f"p[{position[name]}]", fn=fn, states=states)


def _stamp(module_name: str) -> str:
    path = inspect.getfile(sys.modules[module_name])
    return f"# {module_name}: sha256 {hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]}"


def _function(name: str, states: tuple[str, ...], body: list[str], result: str) -> list[str]:
    return ["", "", '@njit(error_model="numpy")', f"def {name}(x, u, p):",
            f"    {state_args(states)} = x", *("    " + line for line in body), f"    return {result}"]


def _state_helpers(n: int) -> list[str]:
    """The kernels' operations on a state held as a tuple of ``n`` floats (:mod:`.kernels`), each
    written out entry by entry: the same floating-point operations as a hand-unrolled loop."""
    def each(expr: str) -> str:
        return "(" + ", ".join(expr.format(k=k) for k in range(n)) + ",)"

    inline = '@njit(inline="always", error_model="numpy")'
    total = " + ".join(f"x[{k}]" for k in range(n))
    return ["", f"N_STATE = {n}",
            "", "", inline, "def _axpy(x, h, a):", f"    return {each('x[{k}] + h * a[{k}]')}",
            "", "", inline, "def _rk4_end(x, s, a, b, c, d):",
            f"    return {each('x[{k}] + s * (a[{k}] + 2.0 * (b[{k}] + c[{k}]) + d[{k}])')}",
            "", "", inline, "def _load(v):", f"    return {each('v[{k}]')}",
            "", "", inline, "def _finite(x):", f"    return math.isfinite({total})"]


def module_source(family: str, states: tuple[str, ...] = ()) -> str:
    """Text of the generated module of ``family`` for rigs whose effects' own states are ``states``
    (module doc).

    Raises
    ------
    AssemblyError
        If a term function is not a module-level function (the module imports it by name).
    """
    built = registry.resolved(family)
    lay = _layout(built)
    imports: list[str] = []
    names: dict[int, str] = {}

    def fn(term: Term) -> str:
        if id(term) not in names:
            f = term.fn
            if f.__qualname__ != f.__name__:
                raise AssemblyError(f"term {term.label!r}: {f.__qualname__} must be a module-level function")
            names[id(term)] = n = f"_f{len(names) + 1}"
            imports.append(f"from {f.__module__} import {f.__name__} as _py{n}")
            imports.append(f'{n} = njit(error_model="numpy")(_py{n})')
        return names[id(term)]

    w = _wiring(built, lay, fn, states)
    body = chain_source(w)
    contacts = [t for t, _ in w.slots.get("rod", ()) if t.contact]
    plain = all(set(t.inputs) <= {"theta", "theta_dot"} for t in contacts)
    code = [*_state_helpers(N_CHAIN + len(states)),
            *_function("rhs", states, body, f"({rates(states)},)"),
            *_function("contact", states, [] if plain else body, w.total("rod", contact=True)),
            *_function("signals", states, body, f"(tau, {w.drive}, i_a, omega_prop, thrust)")]
    sources = sorted({t.fn.__module__ for part in (*built.parts, *built.effects) for t in part.terms})
    kernel_text = Path(kernels.__file__).read_text(encoding="utf-8").partition(KERNELS_MARKER)[2]
    head = [f'"""Generated by aeropend_sim.compiled.source for the {family} family: do not edit.',
            "", f"x = ({state_args(states)})",
            f"p = ({', '.join(lay.keys)}) + flags ({', '.join(lay.flags)})", '"""',
            f"# numba {numba.__version__}", *(_stamp(m) for m in (*sources, xp_numba.__name__)),
            "import math", "", "import numpy as np", "from numba import njit", "",
            "from aeropend_sim.compiled import xp_numba as _xp",
            "from aeropend_sim.components.states import OMEGA, TAU_F", *imports, "",
            f"HAS_CONTACT = {bool(contacts)}"]
    return "\n".join([*head, *code]) + "\n" + kernel_text


def cache_dir() -> Path:
    """Folder of the generated modules (numba caches their machine code in its ``__pycache__``):
    ``$AEROPEND_CACHE_DIR/compiled``, else ``$XDG_CACHE_HOME/aeropend/compiled`` or
    ``~/.cache/aeropend/compiled``."""
    env = os.environ.get(CACHE_ENV)
    base = Path(env) if env else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "aeropend"
    return base / "compiled"


def _write(name: str, text: str) -> Path:
    """Write the module (once: an unchanged file keeps its time stamp, which numba's cache checks)."""
    for folder in (cache_dir(), Path(tempfile.gettempdir()) / f"aeropend-{os.getuid()}" / "compiled"):
        path = folder / f"{name}.py"
        try:
            if path.is_file() and path.read_text(encoding="utf-8") == text:
                return path
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f".{name}.{os.getpid()}.tmp"
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, path)  # atomic: a concurrent process sees the old or the whole new file
            return path
        except OSError as exc:
            warnings.warn(f"cannot write the compiled model to {folder} ({exc}); set {CACHE_ENV} to a "
                          "writable folder", RuntimeWarning, stacklevel=3)
    raise OSError(f"no writable folder for the compiled model (set {CACHE_ENV})")


@registry.derived  # a part registered later may change it
def family_module(family: str, states: tuple[str, ...] = ()) -> ModuleType:
    """The imported generated module of ``family`` for rigs with the effect states ``states`` (the
    names after the chain's in their :class:`~aeropend_sim.components.states.StateLayout`; written
    to :func:`cache_dir` if needed).

    Its functions (:mod:`.kernels`) compile on their first call in a machine's first process and
    load from numba's disk cache afterwards.
    """
    text = module_source(family, states)
    name = f"aeropend_{family}_{hashlib.sha256(text.encode()).hexdigest()[:16]}"
    if name in sys.modules:
        return sys.modules[name]
    path = _write(name, text)
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
