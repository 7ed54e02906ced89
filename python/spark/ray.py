"""Ensembles beyond one process: members sharded over Ray tasks.

:func:`sweep` splits the members into shards, runs each shard as one Ray
task that calls the native ensemble stepper (:func:`spark.ensemble`, all of
the task's threads, GIL released), with fixed or tolerance-driven steps, and
gathers the results into one Parquet file with one row per member and
sample (columns ``member``, ``t``, ``q_<coordinate>``, ``v_<coordinate>``,
``energy``, ``energy_error``, ``constraint``); the returned
:class:`SweepReport` holds each member's step counts.

On one machine ``ray.init()`` starts a local instance. On a cluster, start
Ray there (``ray start --head`` on one node, ``ray start --address=HEAD:6379``
on the others) with this package installed in every node's environment, and
call ``ray.init(address="auto")`` (or pass ``address=`` to :func:`sweep`)
before the sweep: the same code then spreads the shards over the cluster's
nodes. The Parquet file is written by the driver process.

Needs ``ray`` and ``pyarrow`` (``pip install spark-nonholonomic[ray]``).
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import time
import uuid
import warnings
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

import spark


@dataclass
class SweepReport:
    """What :func:`sweep` did: the file, the member and shard counts, the
    wall time of the whole sweep and the time per member, and per member,
    in member order, as :class:`spark.Ensemble` has them: its halvings of
    steps whose Newton iteration failed (``rejected_steps``; see
    :class:`spark.Trajectory`), its accepted steps (``steps``) and, for a
    tolerance-driven sweep, its controller's statistics (``controller``,
    the fields of :class:`spark.ControllerStats` as arrays ``(members,)``;
    ``None`` for fixed steps)."""

    path: str
    members: int
    shards: int
    wall_seconds: float
    rejected_steps: np.ndarray
    steps: np.ndarray | None = None
    controller: dict[str, np.ndarray] | None = None

    @property
    def seconds_per_member(self) -> float:
        return self.wall_seconds / self.members


def _system(system: "spark.System | str", source: tuple[str, str, bool] | None) -> spark.System:
    if source is not None:
        return spark.compile(source[0], cache_dir=source[1], optimize=source[2])
    return spark.system(system) if isinstance(system, str) else system


def _shard_table(system_key, source, method, s, h, steps, q0s, v0s, params, first, threads, options):
    """One shard's table and its members' halvings, accepted steps and
    controller statistics (``options``: the keyword arguments of
    :func:`spark.ensemble` the sweep was given); the driver warns about
    halvings once for the sweep (a worker's warning would not reach the
    user)."""
    import pyarrow as pa

    sys_ = _system(system_key, source)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", spark.StepHalvingWarning)
        e = sys_.ensemble(method, s, h, steps, q0s, v0s, params, threads=threads, **options)
    members, samples = e.energy.shape
    cols: dict[str, np.ndarray] = {
        "member": np.repeat(np.arange(first, first + members, dtype=np.int64), samples),
        "t": np.tile(e.t, members),
    }
    for i, c in enumerate(sys_.coordinates):
        cols[f"q_{c}"] = e.q[:, :, i].reshape(-1)
    for i, c in enumerate(sys_.coordinates):
        cols[f"v_{c}"] = e.v[:, :, i].reshape(-1)
    cols["energy"] = e.energy.reshape(-1)
    cols["energy_error"] = e.energy_error.reshape(-1)
    cols["constraint"] = e.constraint.reshape(-1)
    return pa.table(cols), e.rejected_steps, e.steps, e.controller


def sweep(
    system: "spark.System | str",
    method: str,
    s: int,
    h: float | None = None,
    steps: int | None = None,
    q0s=None,
    v0s=None,
    params: Mapping[str, float] | None = None,
    *,
    out: str = "sweep.parquet",
    t0: float = 0.0,
    t_end: float | None = None,
    every: int | None = None,
    newton: str = "full",
    newton_tol: float | None = None,
    shards: int | None = None,
    threads_per_task: int = 1,
    address: str | None = None,
    max_halvings: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    first_step: float | None = None,
    max_step: float | None = None,
    max_steps: int | None = None,
    t_eval: Sequence[float] | np.ndarray | None = None,
    events: bool = False,
) -> SweepReport:
    """Integrates every row of ``q0s``/``v0s`` on Ray and writes ``out`` (Parquet).

    ``shards`` (default: twice the CPUs Ray reports) tasks each integrate a
    contiguous block of members with ``threads_per_task`` threads, by
    :func:`spark.ensemble` with this call's arguments: fixed steps (``h``
    with ``steps`` or ``t_end``, recorded every ``every`` steps) or
    tolerance-driven ones (``rtol``/``atol`` with ``t_end``, and
    ``first_step``, ``max_step``, ``max_steps``), recorded at the times of
    ``t_eval`` when given (a tolerance-driven sweep without it records
    ``t_end`` alone), with the meaning and the refusals
    :func:`spark.ensemble` gives them. A system
    built by :func:`spark.compile` is rebuilt in each worker from its text
    with its ``optimize`` (loaded from the shared cache on one machine).
    Ray is started with ``ray.init(address=address)`` unless it is already
    running; an ``address`` of ``host:port`` or ``ray://host:port`` is then
    tried with a TCP connection first, and refused with
    :class:`spark.SparkError` naming it when none opens within
    :data:`ADDRESS_TIMEOUT` seconds (``ray.init`` would wait far longer).
    Rows are
    ordered by member, then time, whatever the shard count, and every
    member's numbers are those of :func:`spark.ensemble` (and
    :func:`spark.integrate`) for it alone.
    ``out`` is checked before Ray starts and written under a temporary name
    in its folder, renamed to ``out`` once complete. The other arguments
    are checked before Ray starts too, as :func:`spark.ensemble` checks
    them, then by one step of the first member (fixed steps) or by the
    first member's whole run (tolerance-driven steps, whose steps are known
    only by running them), and
    a table that would not fit in the driver's memory (4 GiB, or half the
    available memory) is refused with the ``every`` (or the number of
    output times) that fits.
    ``max_halvings`` is :meth:`spark.System.integrate`'s; a fixed-step sweep
    in which any member halved a step warns once with
    :class:`spark.StepHalvingWarning`. The report holds each member's
    halvings, accepted steps and (tolerance-driven) controller statistics.
    ``events=True`` is refused with :class:`spark.ArgumentError`: the table
    holds samples only, so the events would be lost; call
    :func:`spark.ensemble` with ``events=True`` (per block of members).
    """
    # Refused before anything else: a sweep that ran and dropped the events
    # would look like one in which none occurred.
    if spark._flag("events", events):
        raise spark.ArgumentError(
            "events=True is not taken by spark.ray.sweep: its Parquet table holds one row per member and sample, "
            "with no place for the located events or the end of a member that a terminal event stops; call "
            "spark.ensemble(..., events=True) (on blocks of members, in Ray tasks of your own if needed)"
        )
    # Missing packages fail here, before any work.
    import pyarrow  # noqa: F401
    import ray  # noqa: F401

    # The arguments are checked here, before Ray starts, as `ensemble`
    # checks them: a bool, a complex number or a string where a real
    # number is meant is a TypeError.
    threads_per_task = spark._whole("threads_per_task", threads_per_task, 1, spark.MAX_THREADS)
    if shards is not None:
        shards = spark._whole("shards", shards, 1)
    address = _address(address)
    q0s, v0s = spark._member_states(q0s, v0s)
    members = q0s.shape[0]
    # A bytes path would meet the str name of the temporary file only when
    # the file is written, after every member has run.
    try:
        out = os.fsdecode(os.fspath(out))
    except TypeError:
        raise TypeError(
            f"out = {spark._short(out)} is not a path; give the path of the Parquet file to write"
        ) from None
    # An empty path and one no file can have are the caller's bad argument
    # whatever the file system holds, as the same in cache_dir of
    # spark.compile; a folder that is missing or not writable stays a
    # SparkError of the file system below.
    if not out:
        raise spark.ArgumentError("out = '' names no file; give the path of the Parquet file to write")
    # The OS takes no path with a NUL, nor one the file system's encoding
    # cannot encode (a lone surrogate such as "\ud800"), and the checks
    # below do not raise for either: the final rename would fail after every
    # member had run.
    if "\0" in out:
        raise spark.ArgumentError(f"out = {out!r} holds a NUL character, which no file name can hold")
    try:
        os.fsencode(out)
    except UnicodeEncodeError as e:
        raise spark.ArgumentError(f"out = {out!r} is no file name: {e}; give a path of valid characters") from e
    folder = os.path.dirname(os.path.abspath(out))
    if os.path.isdir(out) or out.endswith(os.sep):
        raise spark.SparkError(f"out = {out!r} is a folder; give the path of the Parquet file to write")
    if not os.path.isdir(folder):
        raise spark.SparkError(f"the folder of out = {out!r}, {folder}, does not exist; create it first")
    options = dict(t0=t0, t_end=t_end, every=every, newton=newton, newton_tol=newton_tol,
                   max_halvings=max_halvings, rtol=rtol, atol=atol, first_step=first_step, max_step=max_step,
                   max_steps=max_steps, t_eval=t_eval)
    if address is not None and not ray.is_initialized():
        _probe(address)
    # Read once, as a dict: an iterator of pairs has no second pass, and the
    # check below and the shards both read it.
    params = spark._params(params)
    options = _check_before_ray(system, method, s, h, steps, q0s, v0s, params, options)
    # The temporary file is created now, so that a folder that cannot be
    # written (read-only, /proc) is reported before Ray starts.
    temp = _reserve(out, folder)
    try:
        return _sweep(system, method, s, h, steps, q0s, v0s, params, out, temp, options, shards,
                      threads_per_task, address, members)
    finally:
        with contextlib.suppress(OSError):
            os.remove(temp)


#: Seconds :func:`sweep` waits for a TCP connection to ``address`` before
#: it refuses the address.
ADDRESS_TIMEOUT = 5.0

#: The addresses ``ray.init`` resolves itself, without a host and port.
_RAY_WORDS = ("auto", "local")


def _address(address) -> "tuple[str, str, int] | str | None":
    """``address`` checked: ``None`` (a local instance, or ``RAY_ADDRESS``),
    ``"auto"`` or ``"local"`` as given, else ``(address, host, port)`` of
    ``host:port`` or ``ray://host:port``; :class:`TypeError` for what is no
    string, :class:`spark.ArgumentError` for a string that names no host or
    no port."""
    if address is None:
        return None
    if not isinstance(address, str):
        raise TypeError(
            f"address = {spark._short(address)} is not a string; give 'host:port' or 'ray://host:port' of a running "
            "Ray instance, 'auto', 'local', or None"
        )
    spark._utf8(f"address = {spark._short(address)}", address)
    if address in _RAY_WORDS:
        return address
    if not address:
        raise spark.ArgumentError(
            "address = '' names no Ray instance; give 'host:port' or 'ray://host:port', 'auto', 'local', or None for "
            "a local instance"
        )
    host, colon, port_text = address.removeprefix("ray://").rpartition(":")
    port = int(port_text) if port_text.isdecimal() else None
    if not colon or port is None:
        raise spark.ArgumentError(
            f"address = {address!r} names no port; give 'host:port' (the head node's GCS port, 6379 by default) or "
            "'ray://host:port' (the Ray Client's, 10001 by default)"
        )
    host = host.removeprefix("[").removesuffix("]")
    if not host:
        raise spark.ArgumentError(f"address = {address!r} names no host; give 'host:port' or 'ray://host:port'")
    if not 1 <= port <= 65535:
        raise spark.ArgumentError(f"address = {address!r}: port {port} is outside 1..=65535")
    return (address, host, port)


def _probe(address: "tuple[str, str, int] | str") -> None:
    """:class:`spark.SparkError` naming ``address`` when no TCP connection to
    its host and port opens within :data:`ADDRESS_TIMEOUT`: ``ray.init``
    would wait inside Ray's connect for much longer at an address where no
    Ray listens. ``"auto"`` and ``"local"`` are Ray's to resolve."""
    if isinstance(address, str):
        return
    given, host, port = address
    try:
        with socket.create_connection((host, port), timeout=ADDRESS_TIMEOUT):
            pass
    except OSError as e:
        why = "timed out" if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise spark.SparkError(
            f"address = {given!r} cannot be reached: a TCP connection to {host}:{port} failed within "
            f"{ADDRESS_TIMEOUT:g} s ({why}); start Ray there (`ray start --head`), check the host and the port, or "
            "pass address=None for a local instance"
        ) from None


def _row_bytes(n: int) -> int:
    """Bytes of one row of the sweep's table for ``n`` coordinates:
    ``member``, ``t``, ``energy``, ``energy_error``, ``constraint`` and
    ``q``, ``v``, 8 bytes each."""
    return 8 * (2 * n + 5)


#: Copies of the table the driver holds at once: the shards' tables it
#: gathers, and the encoding of the Parquet file.
_TABLE_COPIES = 2


def _check_before_ray(system, method, s, h, steps, q0s, v0s, params, options) -> dict:
    """What the shards would otherwise find only in the workers, after Ray
    has started, checked here: the system (a registered name or a
    :class:`spark.System`), the width of ``q0s``, every argument as
    :func:`spark.ensemble` checks it (its messages, from the same code),
    the table the driver gathers, which must fit in memory as a run's
    record must (each shard checks only its own members), and then the
    method, stage count, parameters, Newton mode and the first member's
    state: by one step of the first member for fixed steps, by its whole run
    for tolerance-driven ones (the runtime's checks of the tolerances,
    ``first_step`` and ``max_step`` come with the run). Returns ``options``
    (the keyword arguments of :func:`spark.ensemble`) for the shards, with
    ``t_eval`` as the checked list of floats."""
    if isinstance(system, str):
        sys_ = spark.system(system)
    elif isinstance(system, spark.System):
        sys_ = system
    else:
        raise TypeError(f"system = {spark._short(system)} is neither a system name nor a spark.System")
    members = q0s.shape[0]
    spark._member_width(q0s, sys_)
    # A table at output times is checked from their count, before they are
    # read (10⁸ times would take gigabytes as the request's list).
    count = None if options["t_eval"] is None else spark._output_count(options["t_eval"])
    if count is not None:
        _check_table(sys_.n, members, 1 + count, None)
    req = sys_._ensemble_request(method, s, h, steps, params, **options, members=None)
    tolerance = "rtol" in req
    times = req.get("t_eval")
    if options["t_eval"] is not None:
        options = dict(options, t_eval=times)
    if times is not None:
        _check_table(sys_.n, members, 1 + len(times), None)
    else:
        n, every = req["steps"], req["every"]
        _check_table(sys_.n, members, n // every + (1 if n % every == 0 else 2), n)
    # The first member alone, as a shard runs it (an ensemble's messages
    # give the advice that applies to a sweep: it has no project_v0).
    common = dict(q0s=q0s[:1], v0s=v0s[:1], params=params, t0=req["t0"], newton=options["newton"],
                  newton_tol=options["newton_tol"], threads=1)
    try:
        with warnings.catch_warnings():
            # Halving is counted over the whole sweep, not for this one step.
            warnings.simplefilter("ignore", spark.StepHalvingWarning)
            if tolerance:
                sys_.ensemble(method, s, t_end=req["t_end"], rtol=req["rtol"], atol=req["atol"],
                              first_step=options["first_step"], max_step=options["max_step"],
                              max_steps=options["max_steps"], t_eval=times, **common)
            else:
                sys_.ensemble(method, s, req["h"], 1, max_halvings=options["max_halvings"], **common)
    except spark.SparkError as e:
        why = str(e).removeprefix("member 0: ")
        raise type(e)(f"the sweep's settings fail on member 0 before any shard runs: {why}") from e
    return options


def _check_table(n: int, members: int, samples: int, steps: int | None) -> None:
    """:class:`spark.ArgumentError` when the table of ``members`` members of
    ``samples`` samples each (``n`` coordinates) would not fit in the
    driver's memory: the driver gathers the whole table, while each shard
    checks only its own members. The message names the record interval that
    fits for ``steps`` fixed steps recorded every so many, or the number of
    output times that fit (``steps`` is ``None``)."""
    rows = members * samples
    need = rows * _row_bytes(n) * _TABLE_COPIES
    limit = spark._native.record_memory_limit()
    if need <= limit:
        return
    fits = limit // (_row_bytes(n) * _TABLE_COPIES) // members
    if fits < 2:
        hint = "sweep fewer members per call (even two samples of each do not fit)"
    elif steps is None:
        hint = f"record at {fits - 1} output times of t_eval or fewer, or sweep fewer members per call"
    else:
        every = steps // max(fits - 2, 1) + 1
        hint = f"record fewer samples with every = {every} or more, or sweep fewer members per call"
    raise spark.ArgumentError(
        f"the sweep's table has {rows:.3e} rows ({need:.3e} bytes in the driver's memory), more than the "
        f"limit of {limit:.3e} bytes (4 GiB or half the available memory); {hint}"
    )


def _reserve(out: str, folder: str) -> str:
    """Creates the empty temporary file the sweep's table is written to, in
    ``out``'s folder (so that the final rename stays on one file system);
    :class:`spark.SparkError` naming ``out`` when the folder cannot be
    written."""
    temp = os.path.join(folder, f".spark-sweep-{os.getpid()}-{uuid.uuid4().hex}.parquet")
    try:
        with open(temp, "xb"):
            pass
    except OSError as e:
        raise spark.SparkError(f"cannot write into the folder of out = {out!r}: {e}") from e
    return temp


def _sweep(system, method, s, h, steps, q0s, v0s, params, out, temp, options, shards, threads_per_task,
           address, members) -> SweepReport:
    """:func:`sweep` once its arguments are checked and ``temp`` exists."""
    import pyarrow as pa
    import ray

    if not ray.is_initialized():
        given = address[0] if isinstance(address, tuple) else address
        try:
            ray.init(address=given, include_dashboard=False, log_to_driver=False)
        except ConnectionError as e:
            if given is None:
                raise
            raise spark.SparkError(f"Ray could not connect to address = {given!r}: {e}") from e
    # Ray keeps a task that asks for more CPUs than any node has waiting for
    # such a node, so the sweep would never end.
    largest = max((n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")), default=0)
    if threads_per_task > largest:
        raise spark.ArgumentError(
            f"threads_per_task = {threads_per_task} is more than the {largest:g} CPUs of the largest Ray node; "
            f"its tasks would wait forever for a node that has them; use threads_per_task ≤ {int(largest)}"
        )
    if shards is None:
        shards = max(1, 2 * int(ray.cluster_resources().get("CPU", 1)))
    shards = max(1, min(shards, members))
    source = None
    if isinstance(system, spark.System) and system.source is not None:
        source = (system.source, system.info["cache_dir"], system.info["optimized"])
    key = system if isinstance(system, str) else system.name
    task = ray.remote(num_cpus=threads_per_task)(_shard_table)
    bounds = np.linspace(0, members, shards + 1).round().astype(int)
    start = time.perf_counter()
    pending = [
        task.remote(key, source, method, s, h, steps, q0s[a:b], v0s[a:b], dict(params or {}), int(a),
                    threads_per_task, options)
        for a, b in zip(bounds[:-1], bounds[1:])
        if b > a
    ]
    tables, halvings, accepted, controllers = zip(*ray.get(pending))
    _write_atomically(pa.concat_tables(tables), out, temp)
    wall = time.perf_counter() - start
    rejected = np.concatenate(halvings)
    controller = None
    if controllers[0] is not None:
        controller = {name: np.concatenate([c[name] for c in controllers]) for name in controllers[0]}
    else:
        # As `ensemble`: the controller of tolerance-driven steps retries a
        # failed step smaller, and counts it in its own statistics.
        spark._warn_halved_members(rejected, None, "the report's rejected_steps", stacklevel=3)
    return SweepReport(
        path=str(out), members=members, shards=len(pending), wall_seconds=wall, rejected_steps=rejected,
        steps=None if any(a is None for a in accepted) else np.concatenate(accepted), controller=controller,
    )


def _write_atomically(table, out: str, temp: str) -> None:
    """Writes ``table`` as Parquet to ``temp`` (a file in ``out``'s folder),
    then renames it to ``out``: an interrupted or failed write leaves an
    earlier ``out`` as it was, never a truncated file under its name. The
    file is opened by Python, which takes any path the OS does (pyarrow
    refuses a path that is not UTF-8)."""
    import pyarrow.parquet as pq

    with open(temp, "wb") as f:
        pq.write_table(table, f)
    os.replace(temp, out)


def ensemble_statistic(table, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Fig. 8.4's statistic ``(1/h⁴)·(1/(J+1)) Σ_j (E_jk − E_j0)²`` at each
    sample time, from a sweep's table (or Parquet path).

    Summed over members in member order and divided as
    ``problems::report::stats::ensemble_quantity`` does, so the numbers are the
    Rust ones bit for bit for the same energies.
    """
    import pyarrow.parquet as pq

    # A step of 0 would divide to inf or NaN, returned as if it were a statistic.
    h = spark._real("h", h)
    if not (math.isfinite(h) and h != 0.0):
        raise spark.ArgumentError(f"h = {h!r} must be a finite, nonzero step size (the sweep's h)")
    columns = ["member", "t", "energy_error"]
    if isinstance(table, (str, bytes)) or hasattr(table, "__fspath__"):
        path = os.fsdecode(os.fspath(table))
        if not path or "\0" in path:
            raise spark.ArgumentError(f"table = {path!r} names no file; pass the Parquet file a sweep wrote")
        try:
            # Opened by Python, which takes any path the OS does (pyarrow
            # refuses a path that is not UTF-8).
            with open(path, "rb") as f:
                table = pq.read_table(f, columns=columns)
        except (KeyError, ValueError) as e:
            # pyarrow's own errors (ArrowInvalid, a ValueError; KeyError for
            # a missing column) name neither the argument nor the remedy.
            raise spark.ArgumentError(
                f"table = {path!r} is not the Parquet file of a sweep ({e}); pass the file a sweep wrote"
            ) from e
    if not (hasattr(table, "column") and hasattr(table, "column_names")):
        raise TypeError(
            f"table = {spark._short(table)} is neither a pyarrow Table nor the path of a sweep's Parquet file"
        )
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise spark.ArgumentError(
            f"the table has no column {', '.join(missing)}; pass the file or table a sweep wrote (its columns: "
            "member, t, …, energy_error)"
        )
    member = table.column("member").to_numpy()
    t = table.column("t").to_numpy()
    err = table.column("energy_error").to_numpy()
    order = np.lexsort((t, member))
    member, t, err = member[order], t[order], err[order]
    ids, counts = np.unique(member, return_counts=True)
    if len(ids) == 0:
        raise spark.ArgumentError("the table has no rows; pass the file or table a sweep wrote")
    # The statistic averages every member at the same sample times: a table
    # whose members have different sample counts is not one sweep's.
    if np.any(counts != counts[0]):
        short = int(ids[np.argmin(counts)])
        raise spark.ArgumentError(
            f"member {short} has {counts.min()} samples and others {counts.max()}: the statistic needs every member "
            "at the same times; pass the table of one sweep"
        )
    samples = int(counts[0])
    # Members of equal counts at other times (tables of two sweeps with
    # different steps) would be averaged as if they were at the first one's.
    times = t.reshape(len(ids), samples)
    differs = np.any(times != times[0], axis=1)
    if np.any(differs):
        other = int(ids[np.argmax(differs)])
        raise spark.ArgumentError(
            f"member {other} has samples at other times than member {int(ids[0])}: the statistic needs every member "
            "at the same times; pass the table of one sweep"
        )
    err = err.reshape(len(ids), samples)
    acc = np.zeros(samples)
    for row in err:  # member after member, as the Rust sum
        acc += row * row
    h2 = h * h
    return t[:samples], acc / len(ids) / (h2 * h2)


#: The most members :func:`fig84_members` builds (112 MB of initial values).
MAX_FIG84_MEMBERS = 10**6


def fig84_members(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial values of the §8.4 ensemble with ``count`` members
    (``problems::systems::mp7_initial_values``), ``1 ≤ count ≤
    MAX_FIG84_MEMBERS``: arrays of shape ``(count, 7)``."""
    count = spark._whole("count", count, 1, MAX_FIG84_MEMBERS)
    q, v = zip(*(spark._native.mp7_initial_values(j, count - 1) for j in range(count)))
    return np.array(q), np.array(v)

