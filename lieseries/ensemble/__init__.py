"""Ensembles: one system from k initial conditions (and per-member parameters), locally or on a Dask cluster.

Modules: :mod:`.plan` (the inputs, checked once), :mod:`.build` (the compiled integrators, from the shared cache),
:mod:`.batch` (the double path), :mod:`.threads` (the scalar path and single runs), :mod:`.cluster` (Dask),
:mod:`.result` (the outputs and their assembly), :mod:`.driver` (:func:`integrate_ensemble`).

Paths
-----
``"double"``
    heyoka's batch mode (:class:`heyoka.taylor_adaptive_batch`): ``batch_size`` members (default
    ``heyoka.recommended_simd_size()``) advance together in the SIMD lanes, each lane with its own step size, so
    every member takes the same steps as its single run. Batches are spread over ``workers`` threads (heyoka
    releases the GIL while it integrates). Each thread works on its own copy of the cached compiled integrator
    (integrators are not thread-safe); one copy per thread, not per batch, because copying an integrator costs
    about as much as integrating eight rigid bodies to T = 20.
``"long double"``, ``"quad"``
    heyoka has no batch mode in these types: the members run one by one on the scalar integrator a single run
    uses (same compiled code and the same steps as the single run; its output rows may differ from the single
    run's in the last place), over ``workers`` threads, each with its own copy.
``events=``
    every member is a single run (heyoka's batch mode keeps no per-lane record of crossings), in any precision,
    over ``workers`` threads; ``sol.events[i]`` holds member i's crossings.
bits (arbitrary precision)
    every member is a single run (:func:`lieseries.taylor.integrate`), one after another, or over
    ``workers`` threads when ``workers`` > 1 (each with its own copy of the cached integrator).

Statuses and the guards
-----------------------
Every member ends with the status its single run would end with. In batch mode heyoka stops the whole batch when
one lane becomes non-finite or hits a terminal event (e.g. a sphere chart's edge). Lanes stopped by a terminal
event keep their state at the event (status from the model's event, as in a single run). For a final time, the
lanes the stop interrupted go on in the batch (the stopped lane is parked at the final time): heyoka's step size
depends on the current state alone, so they take the steps they would have taken anyway. For an output grid they
are run again as single runs. A lane that became non-finite is run again as a single run from its initial
condition, which keeps the last finite state and applies the single run's guards (step collapse, stiffness,
budgets). A lane may take at most ``max_steps`` steps in a batch (default :data:`BATCH_STEPS`, the single run's
threshold for a stiff run): the batch runs in chunks of steps, and a lane that at its current step size would need
more is handed to a single run early, which decides between success, ``step_collapse`` and ``step_budget`` exactly
as for one run (a healthy run longer than :data:`BATCH_STEPS` steps thus runs as a single run unless ``max_steps``
is given). With ``max_time`` or ``min_step``, every member runs as a single run. ``max_time`` bounds the call,
its inputs' checks and all the members (not the one-off compilation of the integrator and its checks): each member's
single run gets the time left when it starts, and members not started when it runs out end ``time_budget`` at their
initial state without running (on a Dask cluster too, against the workers' clocks).

A member that stops early has NaN in the output rows after its stop; ``t_reached``/``y_reached`` give the last
time and state it reached.

Dask
----
``client=`` a :class:`dask.distributed.Client`: the members are cut into chunks (``chunk_size``), and each chunk is
one task that receives the system (pickled: the model or PoissonSystem with its heyoka expressions, never a
compiled integrator), the chunk's initial conditions already rounded to the working precision, and the options;
the worker runs :func:`integrate_ensemble` on its chunk, compiling the integrator once per worker process (its
cache). The chunks are gathered into one :class:`~lieseries.solution.EnsembleSolution`, equal to the local one.
A chunk whose worker dies is rerun (``DASK_RETRIES`` times: on another worker, or on the same one restarted by its
nanny); a closed client, or a chunk that cannot be rerun (a single worker without a nanny), raises a RuntimeError
naming ``client`` with the cause and what to do.
"""

from __future__ import annotations

from .batch import BATCH_STEPS, CHUNK_STEPS  # noqa: F401  (the package keeps the old module's names)
from .build import MAX_BATCH_SIZE, build_batch_integrator, build_scalar_integrator, clear_batch_cache  # noqa: F401
from .cluster import DASK_RETRIES  # noqa: F401
from .propagate import integrate_ensemble

__all__ = ["integrate_ensemble", "build_batch_integrator", "build_scalar_integrator", "clear_batch_cache",
           "BATCH_STEPS"]

#: The default step budget of a member's single run (as :data:`lieseries.taylor.DEFAULT_MAX_STEPS`).
DEFAULT_MAX_STEPS = 50_000_000
