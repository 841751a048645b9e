"""The device Newton's state layout (:mod:`._pcg`), shared with the band solve's decisions (:mod:`._band`):
slots of its float64 scalars (``state``) and int32 counters (``counts``). Their own module, so that both read
one definition and neither imports the other's kernels."""

#: float64 scalars: the tolerance, Φ at the iterate, the step α, ‖Δx‖∞/h, the gradient norm.
TOL, PHI0, ALPHA, STEP_NORM, GNORM = range(5)
#: int32 counters; STEPS and TOTAL: steps and Newton iterations over the solver's life (never cleared).
ITER, CONVERGED, ACCEPTED, TRIALS, BACKTRACKS, RESIDUALS, STEPS, TOTAL = range(8)
