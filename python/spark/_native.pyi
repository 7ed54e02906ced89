"""Type stubs of the extension module `spark._native` (see `spark` for the documented API)."""

from typing import Any

class SparkError(Exception):
    """An error of spark; the message is the Rust library's and says what to change."""

#: The deepest nesting of halved steps a run takes (`max_halvings`).
MAX_HALVINGS: int
#: The most threads an ensemble starts (`threads`).
MAX_ENSEMBLE_THREADS: int

def names() -> list[str]: ...
def catalogue() -> list[tuple[str, str]]: ...
def system_info_of(name: str) -> dict[str, Any]: ...
def integrate(name: str, request: dict[str, Any]) -> dict[str, Any]:
    """One run of the registered system `name` (`spark.System.integrate` builds the request).

    The request: `method`, `s`, `t0`, `q0`, `v0`, `params`, `every`, `newton`,
    `newton_tol`, `multipliers`, `project_v0`, `events` (bool), `t_eval`
    (output times), and either `h`, `steps`, `max_halvings` (fixed steps) or
    `rtol`, `atol`, `first_step`, `max_step`, `max_steps`, `t_end`
    (tolerance-driven steps). The result: `t`, `q`, `v`, `energy`,
    `constraint`, `psi`, `holonomic` (NumPy arrays), the run's statistics,
    `events` (a list of dicts: `name`, `index`, `rising`, `terminal`, `t`,
    `q`, `v`, `step`) and `controller` (a dict of the controller's
    statistics, `None` for fixed steps). The modules `spark.compile` builds
    take and return the same dicts.
    """

def ensemble(name: str, request: dict[str, Any]) -> dict[str, Any]:
    """Many runs of the registered system `name` (`spark.System.ensemble` builds the request).

    The request: that of `integrate` without `q0`, `v0` and with `q0s`,
    `v0s` (one row per member) and `threads`. The result: `t` (samples),
    `q`, `v` (members × samples × N), `energy`, `constraint` (members ×
    samples; NaN after a terminal event ended the member), `e0`, `steps`,
    `newton_iterations_mean`, `rejected_steps`, `smallest_step`, `t_stop`
    (the time each member's run ended) (members), `events` (one list of
    `integrate`'s event dicts per member) and `controller` (a dict of the
    controller's statistics, one entry per member, `None` for fixed steps).
    """

def methods() -> list[tuple[str, str, int, int]]: ...
def mp7_initial_values(j: int, big_j: int) -> tuple[list[float], list[float]]: ...
def check_dsl(text: str) -> dict[str, Any]: ...
def source_dir() -> str: ...
def version() -> str: ...
def record_memory_limit() -> int: ...
def record_bytes_per_sample(n: int, m: int) -> int: ...
