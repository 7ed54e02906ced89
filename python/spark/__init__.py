"""Lagrange–d'Alembert SPARK integrators for nonholonomic systems, from Python.

The integrators are spark's Rust library; this package calls them through a
native extension module. Every system of the Rust registry (``spark list``)
is available by name::

    import spark
    skate = spark.system("skate")
    run = skate.integrate(method="lobatto-iiia-b", s=3, h=0.1, steps=1000)
    run.q, run.v, run.energy          # NumPy arrays

A system can also be declared from Python in the DSL of
``nonholonomic_system!`` with :func:`compile` (needs the Rust toolchain),
and many initial states integrated at once with :func:`ensemble`.
Errors are :class:`SparkError` exceptions carrying the Rust message.
"""

from __future__ import annotations

import difflib
import math
import warnings
from dataclasses import dataclass, field
from sys import float_info
from typing import Any, Mapping, Sequence

import numpy as np

from . import _native
from ._native import SparkError

__all__ = [
    "SparkError",
    "ArgumentError",
    "StepHalvingWarning",
    "DslError",
    "ToolchainError",
    "System",
    "Trajectory",
    "Event",
    "ControllerStats",
    "Ensemble",
    "systems",
    "system",
    "methods",
    "integrate",
    "ensemble",
    "compile",
]

__version__ = _native.version()


class DslError(SparkError):
    """A declaration passed to :func:`compile` is not valid DSL text.

    ``line`` and ``column`` (1-based) point at the offending token of the
    text; the message is what ``nonholonomic_system!`` says at that token.
    """

    def __init__(self, message: str, line: int, column: int):
        super().__init__(f"line {line}, column {column}: {message}")
        self.message = message
        self.line = line
        self.column = column


class ArgumentError(SparkError, ValueError):
    """An argument outside the range the library accepts (``steps=2**70``,
    ``steps=2.5``, ``threads=0``, ``h=0``, ``h=10**400``, ``rtol=-1``,
    ``t0=nan``, a ``t_end`` behind ``t0``, a ``t_eval`` that is not
    monotone, a ``params`` name the system does not have or one named
    twice, ``q0s`` of another width than the system's ``N`` or with a NaN),
    missing (``h`` of a compiled system, ``q0s``), or given together with
    one it does not apply with (``steps`` with ``rtol``, ``every`` with
    ``t_eval``); the message names the argument and the range, and it is
    raised before the run starts. Both a :class:`SparkError` and a
    :class:`ValueError`."""


#: The largest whole-number argument (``s``, ``steps``, ``every``,
#: ``threads``, ``shards``, …): the native module reads them as signed 64-bit
#: integers.
MAX_WHOLE = 2**63 - 1

#: The deepest nesting of halved steps (``max_halvings``), the Rust library's.
MAX_HALVINGS: int = _native.MAX_HALVINGS

#: The most threads an ensemble starts (``threads``, and a sweep's
#: ``threads_per_task``), the Rust library's.
MAX_THREADS: int = _native.MAX_ENSEMBLE_THREADS


class StepHalvingWarning(UserWarning):
    """A run replaced steps whose Newton iteration failed by smaller sub-steps.

    The run succeeded, but it is not a run of fixed steps ``h`` alone: the
    trajectory's ``rejected_steps``, ``substeps`` and ``smallest_step`` say
    how far it departed. Pass ``max_halvings=0`` to make such a step an error
    instead, or turn the warning into one with
    ``warnings.simplefilter("error", spark.StepHalvingWarning)``.
    """


def _warn_halvings(steps: int, halved: int, substeps: int, smallest: float) -> None:
    """Warns (:class:`StepHalvingWarning`) about a run that halved steps."""
    warnings.warn(
        f"{halved} of {steps} steps failed in Newton at the requested h and were covered by {substeps} sub-steps "
        f"in all (smallest {smallest:.6g}): this run is not one of fixed steps h alone; pass max_halvings=0 to "
        "make such a step an error, or a smaller h",
        StepHalvingWarning,
        stacklevel=3,
    )


def _warn_halved_members(rejected: np.ndarray, smallest: np.ndarray | None, where: str, stacklevel: int) -> None:
    """Warns (:class:`StepHalvingWarning`) once about the members of an
    ensemble or a sweep that halved steps, if any: ``rejected`` holds each
    member's halvings, ``smallest`` their smallest sub-steps (when known),
    ``where`` names the field that has the counts."""
    halved = int(np.count_nonzero(rejected))
    if not halved:
        return
    smallest_text = "" if smallest is None else f", smallest sub-step {float(np.min(smallest)):.6g}"
    warnings.warn(
        f"{halved} of {len(rejected)} members halved steps whose Newton iteration failed at the requested h "
        f"({int(np.sum(rejected))} halvings{smallest_text}): they are not runs of fixed steps h alone; see {where}, "
        "pass max_halvings=0 to make such a step an error, or a smaller h",
        StepHalvingWarning,
        stacklevel=stacklevel + 1,
    )


class ToolchainError(SparkError):
    """:func:`compile` needs cargo (the Rust toolchain) and could not run it."""


@dataclass(frozen=True, eq=False)
class Event:
    """One located event of a run with ``events=True``: a zero of an event
    function the system declares (``events: { name: rising(expr) terminal }``
    in its definition).

    ``name`` and ``index`` (its place among the declared events) name it,
    ``rising`` says whether the function rose through zero (``False``: fell),
    ``terminal`` whether it ended the run; ``t`` is the located time,
    ``q`` and ``v`` (read-only arrays of shape ``(N,)``) the state there from
    the continuous extension, ``step`` the index (0-based) of the accepted
    step that holds it. Compared by identity (its fields hold arrays).
    """

    name: str
    index: int
    rising: bool
    terminal: bool
    t: float
    q: np.ndarray
    v: np.ndarray
    step: int


@dataclass(frozen=True)
class ControllerStats:
    """The step-size controller of a tolerance-driven run (``rtol``/``atol``):
    ``accepted`` steps, steps ``rejected`` because the error estimate
    exceeded the tolerance, ``newton_failures`` (steps rejected because a
    Newton solve failed), step ``solves`` (three per attempt: the step and
    the two half steps of the error estimate) and the ``newton_iterations``
    over all of them, and the ``smallest_step`` and ``largest_step``
    magnitudes accepted."""

    accepted: int
    rejected: int
    newton_failures: int
    solves: int
    newton_iterations: int
    smallest_step: float
    largest_step: float


def _event(d: dict[str, Any]) -> Event:
    q, v = d["q"], d["v"]
    q.setflags(write=False)
    v.setflags(write=False)
    return Event(
        name=d["name"],
        index=d["index"],
        rising=d["rising"],
        terminal=d["terminal"],
        t=d["t"],
        q=q,
        v=v,
        step=d["step"],
    )


@dataclass
class Trajectory:
    """One integration run: samples in rows.

    ``t`` has shape ``(samples,)``, ``q`` and ``v`` ``(samples, N)``,
    ``energy`` and ``constraint`` (``max_i |k_i|``) ``(samples,)``; ``psi``
    (multipliers, ``(samples, M)``) only when asked for; ``holonomic``
    (``max_i |g_i(t, q)|``) only for systems with holonomic constraints.
    ``rejected_steps`` counts the halvings of steps whose Newton iteration
    failed (0 for a run of fixed steps ``h`` alone), ``steps_with_rejections``
    the scheduled steps that needed one, ``substeps`` the accepted sub-steps
    (``steps`` without halvings) and ``smallest_step`` the smallest of them.
    ``events`` lists the located events (:class:`Event`, in time order; empty
    unless the run asked for them with ``events=True``); ``controller`` holds
    the controller's statistics of a tolerance-driven run
    (:class:`ControllerStats`; ``None`` for fixed steps).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    energy: np.ndarray
    constraint: np.ndarray
    e0: float
    steps: int
    newton_iterations_mean: float
    psi: np.ndarray | None = None
    holonomic: np.ndarray | None = None
    #: Wall time of the Rust integration call inside (set-up, steps, columns).
    rust_seconds: float = 0.0
    rejected_steps: int = 0
    steps_with_rejections: int = 0
    substeps: int = 0
    smallest_step: float = math.nan
    events: list[Event] = field(default_factory=list)
    controller: ControllerStats | None = None

    @property
    def energy_error(self) -> np.ndarray:
        """``E_k − E0`` at each sample."""
        return self.energy - self.e0


@dataclass
class Ensemble:
    """An ensemble of runs: ``t`` ``(samples,)``; ``q``, ``v``
    ``(members, samples, N)``; ``energy``, ``constraint`` ``(members,
    samples)``; ``e0``, ``rejected_steps`` (halvings of failed steps, see
    :class:`Trajectory`), ``smallest_step`` and ``steps`` (accepted steps)
    ``(members,)``; for tolerance-driven members ``controller``, the fields
    of :class:`ControllerStats` as arrays ``(members,)`` (``None`` for
    fixed steps).

    ``events`` holds one list per member of its located events
    (:class:`Event`, in time order; every list empty unless the ensemble
    asked for them with ``events=True``), and ``t_stop`` ``(members,)``
    the time each member's run ended: ``t[-1]``, or the time of the
    terminal event that ended it (then ``events[j][-1].terminal``). A
    member's ``q``, ``v``, ``energy`` and ``constraint`` are NaN at the
    sample times after its ``t_stop``."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    energy: np.ndarray
    constraint: np.ndarray
    e0: np.ndarray
    newton_iterations_mean: np.ndarray
    rejected_steps: np.ndarray | None = None
    smallest_step: np.ndarray | None = None
    steps: np.ndarray | None = None
    controller: dict[str, np.ndarray] | None = None
    events: list[list[Event]] = field(default_factory=list)
    t_stop: np.ndarray | None = None

    @property
    def energy_error(self) -> np.ndarray:
        """``E_jk − E_j0``, shape ``(members, samples)``."""
        return self.energy - self.e0[:, None]


def _request(
    method: str,
    s: int,
    h: float,
    steps: int,
    t0: float,
    params: Mapping[str, float] | None,
    every: int,
    newton: str,
    newton_tol: float | None,
    max_halvings: int | None,
) -> dict[str, Any]:
    return {
        # The range (0 to 60) and the default are the Rust library's.
        "max_halvings": None if max_halvings is None else _whole("max_halvings", max_halvings, 0, MAX_HALVINGS),
        "method": _text("method", method),
        "s": _whole("s", s, 1),
        "h": _real("h", h),
        "steps": _whole("steps", steps, 1),
        "t0": _real("t0", t0),
        "params": _params(params),
        "every": _whole("every", every, 1),
        "newton": _text("newton", newton),
        "newton_tol": None if newton_tol is None else _real("newton_tol", newton_tol),
    }


def _not_bool(name: str, x: Any) -> None:
    """:class:`TypeError` naming the argument when ``x`` is a bool (or a NumPy
    bool): ``h=True`` would otherwise run as ``h=1.0`` and ``s=True`` as 1."""
    if isinstance(x, (bool, np.bool_)):
        raise TypeError(f"{name} = {x!r} is a bool; pass a number")


def _flag(name: str, x: Any) -> bool:
    """``x`` as a bool; :class:`TypeError` naming the argument for anything
    else: ``project_v0="no"`` is truthy and changed the initial velocity."""
    if not isinstance(x, (bool, np.bool_)):
        raise TypeError(f"{name} = {_short(x)} is not a bool; pass True or False")
    return bool(x)


def _exact(x: float) -> str:
    """``x`` with every digit that tells it apart from its neighbours, as
    the runtime's messages print it (``spark_runtime::Exact``): Python's
    shortest round trip, positional for ``1e-4 <= |x| < 1e16`` and
    scientific beyond, so ``t0 = 1e17`` and ``t_end = 1e17 + 16`` read
    apart."""
    return _rust_exponent(repr(float(x)))


def _rust_exponent(text: str) -> str:
    """A float's text with its exponent written as Rust writes it (``e17``,
    ``e-5``; Python writes ``e+17``, ``e-05``)."""
    if "e" not in text:
        return text
    mantissa, exponent = text.split("e")
    return f"{mantissa}e{int(exponent)}"


def _real(name: str, x: Any) -> float:
    """``x`` as a float; :class:`TypeError` naming the argument for a bool, a
    string, a complex number (``float`` would drop its imaginary part) or
    anything else that is not a real number."""
    _not_bool(name, x)
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name} = {x!r} is a string; pass a number")
    if isinstance(x, (complex, np.complexfloating)):
        raise TypeError(f"{name} = {x!r} is complex; pass a real number")
    try:
        return float(x)
    except OverflowError as e:
        # An int beyond the largest float (10**400) has no float value.
        raise ArgumentError(
            f"{name} = {_short(x)} is too large for a float: its magnitude must be below 1.8e308"
        ) from e
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} = {x!r} is not a number") from e


def _utf8(what: str, x: str) -> str:
    """``x``; :class:`ArgumentError` naming ``what`` (``"name = 'a\\ud800'"``)
    when UTF-8 cannot encode it: a lone surrogate such as ``"\\ud800"``
    (left by decoding bytes with ``errors="surrogateescape"``) cannot cross
    into the Rust library, whose strings are UTF-8."""
    try:
        x.encode("utf-8")
    except UnicodeEncodeError as e:
        raise ArgumentError(
            f"{what} holds the lone surrogate U+{ord(x[e.start]):04X} at index {e.start}, which UTF-8 cannot "
            "encode: it is no valid Unicode text; remove it (text decoded with errors=\"surrogateescape\" keeps "
            "undecodable bytes as such surrogates)"
        ) from None
    return x


def _text(name: str, x: Any) -> str:
    """``x`` as a str: :class:`TypeError` naming the argument for anything
    else, :class:`ArgumentError` for a str UTF-8 cannot encode
    (:func:`_utf8`)."""
    if not isinstance(x, str):
        raise TypeError(f"{name} = {_short(x)} is not a string")
    return _utf8(f"{name} = {_short(x)}", x)


def _short(x: Any) -> str:
    """``repr(x)``, cut to its first and last digits when long (an int such as
    ``10**400`` would fill the message)."""
    r = repr(x)
    return r if len(r) <= 40 else f"{r[:12]}…{r[-6:]} ({len(r)} characters)"


def _whole(name: str, x: Any, low: int | None = None, high: int = MAX_WHOLE) -> int:
    """``x`` as an int in ``low..=high``; :class:`TypeError` for a bool,
    :class:`ArgumentError` when it is not a whole number (``s=2.5`` or
    ``every=1.5`` would otherwise be truncated silently) and naming the
    range outside it (the native module reads 64-bit integers, and PyO3's
    own overflow message names no argument)."""
    _not_bool(name, x)
    try:
        whole = int(x)
    except (TypeError, ValueError, OverflowError):
        whole = None
    try:
        # An array's comparison is an array, whose truth raises ValueError.
        integral = whole is not None and bool(whole == x)
    except (TypeError, ValueError):
        integral = False
    if not integral:
        raise ArgumentError(f"{name} = {_short(x)} must be a whole number")
    if whole > high or (low is not None and whole < low):
        lowest = "" if low is None else f"{low} ≤ "
        side = f"more than {high}" if whole > high else f"less than {low}"
        raise ArgumentError(f"{name} = {_short(whole)} is {side}; give {lowest}{name} ≤ {high}")
    return whole


def _params(params: Mapping[str, float] | None, system: System | None = None) -> dict[str, float] | None:
    """The parameter overrides, each name a string and each value a number
    (a bool is refused). A list of pairs that names a parameter twice is an
    :class:`ArgumentError` (``dict`` would keep the last value silently),
    and so is a name that ``system`` (when given) does not have, naming the
    ones it has: checked here, before the run, rather than as a failure of
    the native run."""
    if params is None:
        return None
    pairs = None
    try:
        if not hasattr(params, "keys"):
            # Read once: an iterator of pairs has no second pass.
            pairs = [tuple(pair) for pair in params]
            if any(len(pair) != 2 for pair in pairs):
                raise ValueError("a pair without two items")
        params = dict(params if pairs is None else pairs)
    except (TypeError, ValueError) as e:
        # `dict("g")`'s own message names neither the argument nor the form.
        raise TypeError(
            f"params = {_short(params)} is not a mapping of parameter names to numbers; write e.g. "
            "params={'g': 9.81}"
        ) from e
    if pairs is not None and len(params) < len(pairs):
        seen: set = set()
        twice = next(name for name, _ in pairs if name in seen or seen.add(name))
        values = ", ".join(_short(value) for name, value in pairs if name == twice)
        raise ArgumentError(
            f"params names {_short(twice)} more than once ({values}); give each parameter once"
        )
    if not params:
        return None
    for name in params:
        if not isinstance(name, str):
            raise TypeError(f"params key {name!r} is not a string; name a parameter, e.g. params={{'g': 9.81}}")
        _utf8(f"params key {_short(name)}", name)
    if system is not None:
        for name in params:
            if name not in system.parameters:
                raise ArgumentError(_unknown_parameter(system, name))
    return {name: _real(f"params[{name!r}]", value) for name, value in params.items()}


def _unknown_parameter(system: System, name: str) -> str:
    """The message for a ``params`` name that ``system`` does not have: the
    names it has, and the closest one."""
    known = list(system.parameters)
    if not known:
        return (
            f"params key {_short(name)}: system `{system.name}` has no parameter `{name}`; it has no parameters at "
            "all, so give params=None"
        )
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean `{close[0]}`?)" if close else ""
    return (
        f"params key {_short(name)}: system `{system.name}` has no parameter `{name}`{hint}; its parameters: "
        f"{', '.join(known)} (see `.parameters` of the system)"
    )


def _time(name: str, x: Any) -> float:
    """``x`` as a finite float: :class:`ArgumentError` naming the argument
    for NaN or ±inf (a run starts and ends at finite times), otherwise as
    :func:`_real`."""
    t = _real(name, x)
    if not math.isfinite(t):
        raise ArgumentError(
            f"{name} = {t!r} is not a finite time; give a finite {name} (magnitude below 1.8e308)"
        )
    return t


def _step_size(h: Any) -> float:
    """``h`` as a float that can be a step: :class:`ArgumentError` naming
    it when it is missing (``None``), NaN, infinite or zero (no run of
    fixed steps advances with it), otherwise as :func:`_real`. The native
    check of the step size refuses the rest (subnormal, above 1.34e154,
    below the resolution of ``t`` at ``t0``) with its reason."""
    if h is None:
        raise ArgumentError(
            "give the step size h= for fixed steps (or rtol=/atol= with t_end= for steps chosen for a tolerance)"
        )
    x = _real("h", h)
    if not math.isfinite(x) or x == 0:
        # In the runtime's words, which the native check uses too.
        shown = "NaN" if math.isnan(x) else repr(x)
        raise ArgumentError(
            f"step size h = {shown} must be finite and nonzero; give a finite h, negative to integrate backward"
        )
    return x


def _steps(h: float, steps: int | None, t_end: float | None, t0: float) -> int:
    """The number of fixed steps of ``h`` from ``t0``: ``steps``, or as many
    as reach ``t_end``. Given both, they must agree: a run of ``steps``
    steps that ended elsewhere than the ``t_end`` also given would return
    another interval than asked, as a success. Every refusal is an
    :class:`ArgumentError`: each is the caller's choice of ``h``, ``steps``,
    ``t0`` or ``t_end``, refused before the run starts."""
    h = _step_size(h)
    if steps is not None:
        n = _whole("steps", steps, 1)
        if t_end is not None:
            h, t_end, t0 = _real("h", h), _real("t_end", t_end), _real("t0", t0)
            ends = t0 + float(n) * h
            try:
                agree = _steps(h, None, t_end, t0) == n
            except SparkError:
                agree = False
            if not agree:
                raise ArgumentError(
                    f"steps = {n} and t_end = {t_end!r} disagree: {n} steps of h = {h!r} from t0 = {t0!r} end at "
                    f"t = {ends!r}; give one of them"
                )
        return n
    if t_end is None:
        raise ArgumentError(
            "give steps= (the number of steps of h) or t_end= (the time the last step ends at); neither was given"
        )
    h, t_end, t0 = _real("h", h), _real("t_end", t_end), _real("t0", t0)
    ratio = (t_end - t0) / h
    if not math.isfinite(ratio):
        # h is finite and nonzero: t_end − t0 overflows (t0 = -1e308,
        # t_end = 1e308), or the quotient does.
        raise ArgumentError(
            f"the interval from t0 = {_exact(t0)} to t_end = {_exact(t_end)} with h = {_exact(h)} is not a "
            "finite number of steps (its length overflows a float); give a t0 and t_end nearer each other, or a "
            "larger h"
        )
    n = round(ratio)
    if n < 1:
        if ratio < 0:
            raise ArgumentError(
                f"t_end = {_exact(t_end)} lies behind t0 = {_exact(t0)} for h = {_exact(h)}: the steps go "
                "from t0 in the direction of h; give h the sign of t_end − t0 (a negative h integrates backward)"
            )
        raise ArgumentError(
            f"the interval from t0 = {_exact(t0)} to t_end = {_exact(t_end)} is shorter than one step of "
            f"h = {_exact(h)}; use a later t_end or a smaller h"
        )
    if n > MAX_WHOLE:
        raise ArgumentError(
            f"the interval from t0 = {_exact(t0)} to t_end = {_exact(t_end)} is {ratio:.3e} steps of "
            f"h = {_exact(h)}, more than {MAX_WHOLE}, the most a run can count; use a larger h or a shorter interval"
        )
    # As `spark run`: relative to the step count, capped at a thousandth of
    # a step (beyond 10⁶ steps a relative tolerance alone accepts an end
    # half a step away, and the run ends elsewhere than asked).
    if abs(ratio - n) > min(1e-9 * n, max(16 * np.finfo(np.float64).eps * n, 1e-3)):
        raise ArgumentError(
            f"the interval from t0 = {_exact(t0)} to t_end = {_exact(t_end)} is {_exact(ratio)} steps of "
            f"h = {_exact(h)}, not a whole number; pass steps= instead, or a t_end a whole number of steps from t0"
        )
    return n


class System:
    """A system: a registered one (:func:`system`) or one built by :func:`compile`.

    Attributes: ``name``, ``type_name``, ``n``, ``m``, ``coordinates``,
    ``parameters`` (defaults), ``structure`` (facts the macro proved),
    ``effects``, ``events`` (the declared events that ``integrate(...,
    events=True)`` locates: dicts of ``name``, ``direction`` — ``"rising"``,
    ``"falling"`` or ``"crossing"`` —, ``terminal`` and ``function``, the
    event function's text; empty when it declares none), and for registered
    systems ``description``, ``q0``,
    ``v0``, ``h``, ``t_end`` (the defaults of ``spark run``).
    """

    def __init__(self, info: dict[str, Any], integrate_fn, ensemble_fn):
        self.info = info
        self._integrate = integrate_fn
        self._ensemble = ensemble_fn
        self.name: str = info.get("name", info["type_name"])
        self.type_name: str = info["type_name"]
        self.n: int = info["n"]
        self.m: int = info["m"]
        self.coordinates: list[str] = list(info["coordinates"])
        self.parameters: dict[str, float] = dict(info["parameters"])
        self.structure: dict[str, Any] = dict(info["structure"])
        self.effects: dict[str, bool] = dict(info["effects"])
        self.events: list[dict[str, Any]] = [dict(e) for e in info.get("events", [])]
        self.description: str = info.get("description", "")
        self.q0: list[float] | None = info.get("q0")
        self.v0: list[float] | None = info.get("v0")
        self.h: float | None = info.get("h")
        self.t_end: float | None = info.get("t_end")
        #: The DSL text of a system built by :func:`compile` (``None`` for registered ones).
        self.source: str | None = None

    def __repr__(self) -> str:
        return f"<spark.System {self.name}: N = {self.n}, M = {self.m}>"

    def integrate(
        self,
        method: str = "gauss",
        s: int = 2,
        h: float | None = None,
        steps: int | None = None,
        *,
        t_end: float | None = None,
        t0: float = 0.0,
        q0: Sequence[float] | None = None,
        v0: Sequence[float] | None = None,
        params: Mapping[str, float] | None = None,
        every: int | None = None,
        newton: str = "full",
        newton_tol: float | None = None,
        multipliers: bool = False,
        project_v0: bool = False,
        max_halvings: int | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        first_step: float | None = None,
        max_step: float | None = None,
        max_steps: int | None = None,
        t_eval: Sequence[float] | np.ndarray | None = None,
        events: bool = False,
    ) -> Trajectory:
        """Integrates from ``(t0, q0, v0)`` with ``steps`` fixed steps of ``h``,
        or with steps chosen for a tolerance (``rtol``/``atol``).

        ``method`` is one of :func:`methods` (``gauss``, ``lobatto-iiia-b``,
        ``lobatto-iiia-b-d``, ``euler-1``, ``euler-2``,
        ``modified-lobatto-iiia-b``, ``lobatto-iiib-a-lda``), ``s`` its stage
        count. ``q0``, ``v0``, ``h`` and the final time default to the
        system's (``spark list``). ``every`` records every so many steps
        (default 1; always the endpoints); ``multipliers=True`` also records ψ.
        A step whose Newton iteration fails is replaced by two half steps,
        nested at most ``max_halvings`` levels deep (default 4, at most 60;
        ``0`` makes the failure an error); a run that halved any step warns
        with :class:`StepHalvingWarning` and counts them in the result.
        The same steps as ``spark run`` with the same options, bit for bit.

        Tolerance-driven steps: ``rtol`` and/or ``atol`` (the one not given
        takes the given one's value; finite, ≥ 0, not both 0) switch the run to
        step sizes chosen by a step-doubling error estimate and a PI
        controller, from ``t0`` to ``t_end`` (required; the last step lands on
        it). ``first_step`` is the magnitude of the first step tried (default:
        estimated), ``max_step`` the largest step magnitude (default: the
        whole interval), ``max_steps`` the most step attempts, accepted and
        rejected (default 1 000 000; also what bounds the recorded samples).
        ``h``, ``steps`` and ``max_halvings`` do not apply and are refused.
        The result's ``controller`` holds the controller's statistics.

        ``t_eval`` (a 1-D array of times, strictly monotone in the direction
        of the run, within ``[t0, t_end]``; ``t_end`` being ``t0 + steps·h``
        for fixed steps) records the state at these times from the continuous
        extension of the step that holds each (the steps are not shortened to
        land on them) instead of at the steps: the samples are the initial
        point and then one per time, and the run ends at the last time.
        ``every`` does not apply and is refused with it.

        ``events=True`` locates the events the system declares
        (``events: { name: rising(expr) terminal, … }`` in its definition) and
        returns them in the result's ``events``; a terminal one ends the run
        there (its state is the last sample). A system that declares none
        raises :class:`SparkError`.

        Raises :class:`SparkError` with the Rust message on bad input or a
        failed step (:class:`ArgumentError` for an argument out of range or
        given with one it does not apply with, :class:`TypeError` for an
        argument of the wrong type).
        """
        t0 = _time("t0", t0)
        t_end = None if t_end is None else _time("t_end", t_end)
        params = _params(params, self)
        if rtol is not None or atol is not None:
            req = self._tolerance_request(method, s, h, steps, t_end, t0, rtol, atol, first_step, max_step,
                                          max_steps, max_halvings)
            interval_end = req["t_end"]
        else:
            _refuse_tolerance_arguments(first_step, max_step, max_steps)
            h = _step_size(self.h if h is None else h)
            if steps is None and t_end is None and self.t_end is not None:
                t_end = t0 + self.t_end
                if math.isfinite(t0) and not t_end > t0:
                    raise ArgumentError(
                        f"t0 = {_exact(t0)} leaves no interval to run: the default end, t0 + {self.t_end} (the "
                        f"system's run length), is {_exact(t_end)}, not after t0 at this magnitude; pass t_end= or "
                        "steps=, or a t0 nearer 0"
                    )
            n = _steps(h, steps, t_end, t0)
            req = _request(method, s, h, n, t0, params, 1, newton, newton_tol, max_halvings)
            # As the runtime computes the end of a run of fixed steps.
            interval_end = t0 + float(n) * h
        req["params"] = params
        req["newton"] = _text("newton", newton)
        req["newton_tol"] = None if newton_tol is None else _real("newton_tol", newton_tol)
        if t_eval is not None:
            _refuse_every_with_output_times(every)
            req["t_eval"] = _output_times(t_eval, t0, interval_end, self._sample_bytes(), 1)
        req["every"] = 1 if every is None else _whole("every", every, 1)
        req["events"] = _flag("events", events)
        req["q0"] = _vector("q0", q0 if q0 is not None else self.q0, self)
        req["v0"] = _vector("v0", v0 if v0 is not None else self.v0, self)
        req["multipliers"] = _flag("multipliers", multipliers)
        req["project_v0"] = _flag("project_v0", project_v0)
        d = self._integrate(req)
        if "controller" not in d and ("rtol" in req or "t_eval" in req or req["events"]):
            # A module built by an older spark.compile reads none of these keys.
            raise SparkError(
                f"the module of {self.name} predates rtol, t_eval and events and ran another request; delete its "
                "folder in spark.compile's cache (SPARK_CACHE_DIR or ~/.cache/spark-python) and compile it again"
            )
        controller = d.get("controller")
        if controller is None and d["rejected_steps"]:
            _warn_halvings(d["steps"], d["steps_with_rejections"], d["substeps"], d["smallest_step"])
        return Trajectory(
            t=d["t"],
            q=d["q"],
            v=d["v"],
            energy=d["energy"],
            constraint=d["constraint"],
            e0=d["e0"],
            steps=d["steps"],
            newton_iterations_mean=d["newton_iterations_mean"],
            psi=d.get("psi") if multipliers else None,
            holonomic=d.get("holonomic"),
            rust_seconds=d["rust_seconds"],
            rejected_steps=d["rejected_steps"],
            steps_with_rejections=d["steps_with_rejections"],
            substeps=d["substeps"],
            smallest_step=d["smallest_step"],
            events=[_event(e) for e in d.get("events", [])],
            controller=None if controller is None else ControllerStats(**controller),
        )

    def _tolerance_request(self, method, s, h, steps, t_end, t0, rtol, atol, first_step, max_step, max_steps,
                           max_halvings) -> dict[str, Any]:
        """The request of a tolerance-driven run (:meth:`integrate` with
        ``rtol``/``atol``), its arguments checked."""
        for name, given in (("h", h), ("steps", steps), ("max_halvings", max_halvings)):
            if given is not None:
                raise ArgumentError(
                    f"{name} = {_short(given)} does not apply to a tolerance-driven run (rtol/atol): the controller "
                    f"chooses the steps; drop {name}, or drop rtol and atol for fixed steps"
                )
        if t_end is None:
            raise ArgumentError(
                "a tolerance-driven run (rtol/atol) needs t_end=, the time its last step lands on"
            )
        if t_end == t0:
            raise ArgumentError(
                f"t_end = {t_end!r} is t0: a tolerance-driven run needs an interval to step over; give a t_end "
                "other than t0 (before it to integrate backward)"
            )
        for name, x in (("rtol", rtol), ("atol", atol)):
            if x is not None and not (math.isfinite(_real(name, x)) and x >= 0):
                raise ArgumentError(f"{name} = {_real(name, x)!r} must be finite and ≥ 0")
        rtol = None if rtol is None else _real("rtol", rtol)
        atol = None if atol is None else _real("atol", atol)
        # The one not given takes the given one's value.
        rtol = atol if rtol is None else rtol
        atol = rtol if atol is None else atol
        if rtol == 0 and atol == 0:
            raise ArgumentError("rtol and atol are both 0; give a positive rtol or atol")
        req: dict[str, Any] = {
            "method": _text("method", method),
            "s": _whole("s", s, 1),
            "t0": t0,
            "t_end": _real("t_end", t_end),
            "rtol": rtol,
            "atol": atol,
            "max_steps": None if max_steps is None else _whole("max_steps", max_steps, 1),
        }
        if first_step is not None:
            x = _real("first_step", first_step)
            if not (math.isfinite(x) and x > 0):
                raise ArgumentError(f"first_step = {x!r} must be finite and positive (a step magnitude)")
            # Below the smallest normal float 1/h overflows in a step.
            if x < float_info.min:
                raise ArgumentError(f"first_step = {x!r} is subnormal; give at least 2.2e-308")
            req["first_step"] = x
        if max_step is not None:
            x = _real("max_step", max_step)
            if not x > 0:
                raise ArgumentError(f"max_step = {x!r} must be positive (a step magnitude)")
            req["max_step"] = x
        return req

    def ensemble(
        self,
        method: str,
        s: int,
        h: float | None = None,
        steps: int | None = None,
        q0s=None,
        v0s=None,
        params: Mapping[str, float] | None = None,
        *,
        t0: float = 0.0,
        t_end: float | None = None,
        every: int | None = None,
        newton: str = "full",
        newton_tol: float | None = None,
        threads: int | None = None,
        max_halvings: int | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        first_step: float | None = None,
        max_step: float | None = None,
        max_steps: int | None = None,
        t_eval: Sequence[float] | np.ndarray | None = None,
        events: bool = False,
    ) -> Ensemble:
        """Integrates every row of ``q0s``/``v0s`` (shape ``(members, N)``)
        with the same method, steps and parameters, on ``threads`` threads
        (default: all cores, or ``RAYON_NUM_THREADS``), with the GIL
        released. Each member agrees with what :meth:`integrate` returns for
        it alone with the same arguments to the Newton tolerance per step,
        and is the same whatever the thread count.

        Fixed steps: ``steps`` steps of ``h`` (or as many as reach
        ``t_end``), recorded every ``every`` steps (default 1; always the
        endpoints). A compiled system and the McLachlan–Perlmutter particles
        run in SIMD lane groups of the native lane stepper
        (``integrate_ensemble``), the other registered systems one run per
        member. A member whose step fails runs alone, with the halving of
        :meth:`integrate` (``max_halvings``); if any member halved a step the
        call warns with :class:`StepHalvingWarning`.

        Tolerance-driven steps: ``rtol`` and/or ``atol`` with ``t_end`` (and
        ``first_step``, ``max_step``, ``max_steps``), as in
        :meth:`integrate`; each member's controller chooses its own steps,
        one run per member. The members are recorded at common times: the
        initial point and each time of ``t_eval`` (default: ``t_end`` alone),
        from the continuous extension of the step that holds it; the result's
        ``controller`` holds each member's statistics and ``steps`` its
        accepted steps. ``t_eval`` records fixed-step members the same way.

        ``events=True`` locates the events the system declares in every
        member, as :meth:`integrate` does: each member then runs alone (one
        run per member in parallel, never in SIMD lane groups), with fixed or
        tolerance-driven steps, and its ``events`` (``result.events[j]``) and
        samples are, bit for bit, those of :meth:`integrate` for it alone. A
        terminal event ends its member only: the member keeps its samples at
        the ensemble's sample times up to the event (the grid of ``every``
        steps, or the initial point and the times of ``t_eval``; at the
        event's time itself only when that is one of them) and is NaN at the
        later ones (``q``, ``v``, ``energy``, ``constraint``); its state at
        the event is ``events[j][-1]``, and ``t_stop[j]`` the event's time
        where the members that ran to the end have ``t[-1]``. A system that
        declares no events raises :class:`SparkError`.
        """
        q0s, v0s = _member_states(q0s, v0s)
        _member_width(q0s, self)
        req = self._ensemble_request(method, s, h, steps, params, t0, t_end, every, newton, newton_tol,
                                     max_halvings, rtol, atol, first_step, max_step, max_steps, t_eval,
                                     members=q0s.shape[0])
        req["q0s"] = q0s.tolist()
        req["v0s"] = v0s.tolist()
        req["threads"] = None if threads is None else _whole("threads", threads, 1, MAX_THREADS)
        req["events"] = _flag("events", events)
        d = self._ensemble(req)
        if "t_stop" not in d and req["events"]:
            # A module built by an older spark.compile reads no `events` of an
            # ensemble and returns neither events nor end times.
            raise SparkError(
                f"the module of {self.name} predates events in ensembles; delete its folder in spark.compile's "
                "cache (SPARK_CACHE_DIR or ~/.cache/spark-python) and compile it again"
            )
        controller = d.get("controller")
        if controller is None:
            _warn_halved_members(d["rejected_steps"], d["smallest_step"], "the ensemble's rejected_steps",
                                 stacklevel=2)
        return Ensemble(
            t=d["t"],
            q=d["q"],
            v=d["v"],
            energy=d["energy"],
            constraint=d["constraint"],
            e0=d["e0"],
            newton_iterations_mean=d["newton_iterations_mean"],
            rejected_steps=d["rejected_steps"],
            smallest_step=d["smallest_step"],
            steps=d.get("steps"),
            controller=controller,
            events=[[_event(e) for e in member] for member in d.get("events", [[]] * len(q0s))],
            t_stop=d["t_stop"] if "t_stop" in d else np.full(len(q0s), d["t"][-1]),
        )

    def _ensemble_request(self, method, s, h, steps, params, t0, t_end, every, newton, newton_tol, max_halvings,
                          rtol, atol, first_step, max_step, max_steps, t_eval,
                          members: int | None = 1) -> dict[str, Any]:
        """The request of :meth:`ensemble` without its members and threads,
        every argument checked with its messages; ``spark.ray.sweep`` checks
        its arguments with it too, before Ray starts. Fixed steps carry
        ``steps`` (the count), tolerance-driven steps ``rtol``; both carry
        ``t_eval`` when the samples are at output times (always for
        tolerance-driven steps: ``t_end`` alone by default), its count
        checked against the record of ``members`` runs first (``None``:
        the caller has checked it)."""
        t0 = _time("t0", t0)
        t_end = None if t_end is None else _time("t_end", t_end)
        params = _params(params, self)
        if t_eval is not None:
            _refuse_every_with_output_times(every)
        tolerance = rtol is not None or atol is not None
        if tolerance:
            req = self._tolerance_request(method, s, h, steps, t_end, t0, rtol, atol, first_step, max_step,
                                          max_steps, max_halvings)
            if every is not None:
                raise ArgumentError(
                    f"every = {_short(every)} does not apply to a tolerance-driven ensemble: each member's "
                    "controller chooses its own steps, so the members are recorded at the common times of t_eval "
                    "(default: t_end alone); drop every"
                )
            interval_end = req["t_end"]
            if t_eval is None:
                t_eval = [interval_end]
            req.update(params=params, newton=_text("newton", newton), every=1,
                       newton_tol=None if newton_tol is None else _real("newton_tol", newton_tol))
        else:
            _refuse_tolerance_arguments(first_step, max_step, max_steps)
            h = _step_size(h)
            n = _steps(h, steps, t_end, t0)
            req = _request(method, s, h, n, t0, params, 1 if every is None else every, newton, newton_tol,
                           max_halvings)
            # As the runtime computes the end of a run of fixed steps.
            interval_end = t0 + float(n) * _real("h", h)
        if t_eval is not None:
            req["t_eval"] = _output_times(t_eval, t0, interval_end, self._sample_bytes(), members)
        return req

    def _sample_bytes(self) -> int:
        """Bytes of one recorded sample of this system, as the native check
        of a registered system's record counts them (a compiled module's
        record takes at least as many)."""
        return _native.record_bytes_per_sample(self.n, self.m)


def _members_given(q0s, v0s) -> None:
    """:class:`ArgumentError` when the initial states of an ensemble are
    missing, naming the one that is."""
    missing = [name for name, x in (("q0s", q0s), ("v0s", v0s)) if x is None]
    if missing:
        raise ArgumentError(
            f"give the initial states q0s= and v0s=, arrays of shape (members, N) ({' and '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} missing)"
        )


def _member_states(q0s, v0s) -> tuple[np.ndarray, np.ndarray]:
    """``q0s`` and ``v0s`` as float64 arrays of one shape ``(members, N)``
    with at least one member and finite entries: :class:`ArgumentError`
    naming what is wrong (a missing one, a 1-D array, two shapes, an entry
    that is not finite) before any member runs, :class:`TypeError` for
    entries that are no real numbers. A NaN or an infinity would otherwise
    fail as one member's run, after the members before it had run."""
    _members_given(q0s, v0s)
    _real_entries("q0s", q0s)
    _real_entries("v0s", v0s)
    q0s = _floats("q0s", q0s)
    v0s = _floats("v0s", v0s)
    for name, x in (("q0s", q0s), ("v0s", v0s)):
        if x.ndim != 2:
            one = " (one member's state is a row: write [q0])" if x.ndim == 1 else ""
            raise ArgumentError(
                f"{name} must be a 2-D array of shape (members, N), one row per member; got shape {x.shape}{one}"
            )
    if q0s.shape != v0s.shape:
        raise ArgumentError(
            f"q0s and v0s must have the same shape (members, N), a row of each per member; got {q0s.shape} and "
            f"{v0s.shape}"
        )
    if q0s.shape[0] == 0:
        raise ArgumentError("an ensemble needs at least one member; give q0s and v0s of shape (members, N) with "
                            "members ≥ 1")
    for name, x in (("q0s", q0s), ("v0s", v0s)):
        bad = np.argwhere(~np.isfinite(x))
        if bad.size:
            j, i = (int(k) for k in bad[0])
            raise ArgumentError(
                f"{name}[{j}, {i}] = {float(x[j, i])!r} is not finite (member {j}); give finite initial states"
            )
    return q0s, v0s


def _member_width(q0s: np.ndarray, system: System) -> None:
    """:class:`ArgumentError` when the rows of ``q0s`` (and ``v0s``, of the
    same shape) do not have the system's ``N`` entries."""
    if q0s.shape[1] != system.n:
        raise ArgumentError(
            f"q0s and v0s must have shape (members, {system.n}) for {system.name} ({', '.join(system.coordinates)}); "
            f"got {q0s.shape}"
        )


def _refuse_tolerance_arguments(first_step, max_step, max_steps) -> None:
    """:class:`ArgumentError` for an argument of tolerance-driven runs given
    to a run of fixed steps."""
    for name, given in (("first_step", first_step), ("max_step", max_step), ("max_steps", max_steps)):
        if given is not None:
            raise ArgumentError(
                f"{name} = {_short(given)} applies to tolerance-driven runs only; pass rtol= (or atol=) too, "
                f"or drop {name}"
            )


def _refuse_every_with_output_times(every) -> None:
    """:class:`ArgumentError` for ``every`` given with ``t_eval``: the
    samples are then at the output times, not at the steps."""
    if every is not None:
        raise ArgumentError(
            f"every = {_short(every)} does not apply with t_eval: the samples are the initial point and the "
            "state at each output time; drop every, or drop t_eval to record at the steps"
        )


def _not_real(x) -> str | None:
    """What ``x`` (a number, or an array, list or tuple of them) holds that
    is no real number but that NumPy's cast to float64 takes: ``"a bool"``
    (``[True, 0, 0]`` would run as ``[1.0, 0.0, 0.0]``), ``"a complex number"``
    (its imaginary part dropped) or ``"a string"`` (parsed); ``None`` when
    it holds none."""
    if isinstance(x, np.ndarray):
        kind = {"b": "a bool", "c": "a complex number", "U": "a string", "S": "a string"}.get(x.dtype.kind)
        if kind is not None or x.dtype != object:
            return kind
        return next((k for k in map(_not_real, x.flat) if k is not None), None)
    if isinstance(x, (list, tuple)):
        return next((k for k in map(_not_real, x) if k is not None), None)
    if isinstance(x, (bool, np.bool_)):
        return "a bool"
    if isinstance(x, (complex, np.complexfloating)):
        return "a complex number"
    if isinstance(x, (str, bytes)):
        return "a string"
    return None


def _real_entries(what: str, x) -> None:
    """:class:`TypeError` naming ``what`` when ``x`` holds a bool, a complex
    number or a string (:func:`_not_real`)."""
    kind = _not_real(x)
    if kind is not None:
        raise TypeError(f"{what} holds {kind}; pass real numbers")


def _floats(what: str, x) -> np.ndarray:
    """``x`` as a float64 array; :class:`ArgumentError` naming ``what`` when
    an entry is an int beyond the largest float (NumPy's own message names
    no argument)."""
    if x is None or (isinstance(x, (list, tuple)) and any(e is None for e in x)):
        # NumPy reads None as NaN, and the message would name a NaN the
        # caller never wrote.
        raise TypeError(f"{what} holds None; pass real numbers")
    try:
        return np.ascontiguousarray(x, dtype=np.float64)
    except OverflowError as e:
        raise ArgumentError(
            f"{what} holds an integer too large for a float: its magnitude must be below 1.8e308"
        ) from e
    except (TypeError, ValueError) as e:
        # NumPy's own message ("float() argument must be a string or a real
        # number, not 'dict'", "inhomogeneous shape") names no argument.
        raise TypeError(f"{what} = {_short(x)} is not an array of real numbers: {e}") from e


def _vector(what: str, x, system: System) -> list[float]:
    """``x`` as the list of the ``N`` finite floats of ``system``'s initial
    ``q0`` or ``v0`` (``what``): :class:`ArgumentError` naming it when it
    is missing, not 1-D, of another length or not finite, before the run
    starts."""
    if x is None:
        raise ArgumentError(f"give {what}=, the initial {what[0]} of {system.name} ({system.n} numbers)")
    _real_entries(what, x)
    a = _floats(what, x)
    if a.ndim != 1:
        raise ArgumentError(f"{what} must be a vector of {system.n} numbers; got shape {a.shape}")
    if a.size != system.n:
        raise ArgumentError(
            f"{what} has {a.size} entries but {system.name} has {system.n} coordinates "
            f"({', '.join(system.coordinates)}); give one entry per coordinate"
        )
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ArgumentError(f"{what}[{int(bad[0])}] = {float(a[bad[0]])!r} is not finite; give a finite {what}")
    return a.tolist()


def _sci(x: float) -> str:
    """``x`` as the Rust library writes it in its messages (``1.000e8``)."""
    return _rust_exponent(f"{x:.3e}")


def _output_count(t_eval) -> int | None:
    """How many times ``t_eval`` holds, without reading them (``None`` for
    an object without a length, which is read and checked instead)."""
    if isinstance(t_eval, np.ndarray):
        return t_eval.size
    try:
        return len(t_eval)
    except TypeError:
        return None


def _check_output_count(t_eval, sample_bytes: int, members: int) -> None:
    """:class:`ArgumentError` when the samples ``members`` runs record at
    the times of ``t_eval`` (the initial point and one per time, at
    ``sample_bytes`` each) would not fit within the record's limit
    (:func:`_native.record_memory_limit`), from the count alone: the times
    are not read (as floats, then as the list the request carries, 10⁸
    times would take 3 GB before the native check of the record refused
    them). A ``t_eval`` without a length passes, to be read and checked."""
    count = _output_count(t_eval)
    if count is None:
        return
    samples = members * (count + 1)
    need = samples * sample_bytes
    limit = _native.record_memory_limit()
    if need <= limit:
        return
    fits = max(limit // sample_bytes // members - 1, 0)
    who = "the run" if members == 1 else f"the {members} members"
    hint = f"give at most {fits} output times" if fits else "even one output time does not fit: use fewer members"
    raise ArgumentError(
        f"t_eval holds {_sci(count)} times: {who} would record {_sci(samples)} samples ({_sci(need)} bytes in "
        f"memory), more than the limit of {_sci(limit)} bytes (4 GiB or half the available memory); {hint}"
    )


def _output_times(t_eval, t0: float, t_end: float, sample_bytes: int, members: int | None) -> list[float]:
    """``t_eval`` as a list of floats: a non-empty 1-D array of finite times,
    strictly monotone in the direction from ``t0`` to ``t_end``, within
    ``[t0, t_end]``, whose samples for ``members`` runs fit in memory
    (:func:`_check_output_count`, before the times are read; ``None``: the
    caller has checked the count); :class:`ArgumentError`
    (:class:`TypeError` for entries that are no real numbers) naming what
    is wrong."""
    if members is not None:
        _check_output_count(t_eval, sample_bytes, members)
    _real_entries("t_eval", t_eval)
    times = _floats("t_eval", t_eval)
    if times.ndim != 1 or times.size == 0:
        raise ArgumentError(f"t_eval must be a non-empty 1-D array of times; got shape {times.shape}")
    if not np.all(np.isfinite(times)):
        raise ArgumentError(f"t_eval holds a non-finite time {times[~np.isfinite(times)][0]!r}")
    low, high = min(t0, t_end), max(t0, t_end)
    outside = (times < low) | (times > high)
    if np.any(outside):
        raise ArgumentError(
            f"t_eval holds t = {float(times[outside][0])!r}, outside the run's interval from t0 = {t0!r} to "
            f"t_end = {t_end!r}; give times within it"
        )
    steps = np.diff(times) * (1.0 if t_end >= t0 else -1.0)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        direction = "increasing" if t_end >= t0 else "decreasing (the run goes backward)"
        raise ArgumentError(
            f"t_eval must be strictly {direction}: t_eval[{k + 1}] = {float(times[k + 1])!r} follows "
            f"t_eval[{k}] = {float(times[k])!r}"
        )
    return times.tolist()


def systems() -> list[str]:
    """Every registered system name (the paper's four first), as ``spark list``."""
    return list(_native.names())


def system(name: str) -> System:
    """The registered system ``name`` (any case; ``-``/``_`` ignored).
    Unknown names raise :class:`ArgumentError` with the closest name."""
    info = _native.system_info_of(_text("name", name))
    key = info["name"]
    return System(info, lambda req: _native.integrate(key, req), lambda req: _native.ensemble(key, req))


def methods() -> list[tuple[str, str, int, int]]:
    """``(key, name, smallest s, largest s)`` of every method."""
    return list(_native.methods())


def _as_system(sys: System | str) -> System:
    return sys if isinstance(sys, System) else system(sys)


def integrate(sys: System | str, method: str = "gauss", s: int = 2, h: float | None = None,
              steps: int | None = None, **kwargs) -> Trajectory:
    """``system(sys).integrate(method, s, h, steps, **kwargs)``."""
    return _as_system(sys).integrate(method, s, h, steps, **kwargs)


def ensemble(sys: System | str, method: str, s: int, h: float | None = None, steps: int | None = None, q0s=None,
             v0s=None, params: Mapping[str, float] | None = None, **kwargs) -> Ensemble:
    """Integrates many initial states at once (see :meth:`System.ensemble`)."""
    return _as_system(sys).ensemble(method, s, h, steps, q0s, v0s, params, **kwargs)


def compile(text: str, *, cache_dir: str | None = None, verbose: bool = False, optimize: bool = True) -> System:
    """Builds a system from DSL text (the body of ``nonholonomic_system!``).

    The text is checked by the macro's own parser first (a bad declaration
    raises :class:`DslError` with line and column, without running cargo),
    then compiled by cargo into a native module cached under a hash of the
    text and the spark version (``~/.cache/spark-python`` or
    ``SPARK_CACHE_DIR``); a second call with the same text loads the cached
    module. Needs the Rust toolchain (``cargo``) at run time, as CasADi's
    ``jit`` needs a C compiler; without it raises :class:`ToolchainError`.

    ``cache_dir`` (default ``None``: ``SPARK_CACHE_DIR`` or
    ``~/.cache/spark-python``) must name a folder: an empty path, one
    holding a NUL character or a lone surrogate is refused with
    :class:`ArgumentError` before the text is checked, and so is an empty
    ``SPARK_CACHE_DIR`` when no ``cache_dir`` is given.

    ``optimize=False`` builds the module without optimization: a new
    declaration compiles in seconds instead of tens of seconds and steps
    about 40 times slower, with the same results bit for bit (for trying
    declarations out, not for long runs). The two builds are cached apart.
    ``SPARK_COMPILE_OPTIMIZE=0`` in the environment builds every module of
    the process, and of the interpreters it starts, as ``optimize=False``
    does (``1`` or unset: ``optimize`` decides; another value raises
    :class:`ArgumentError`).
    """
    from ._compile import compile_system

    return compile_system(text, cache_dir=cache_dir, verbose=verbose, optimize=optimize)
