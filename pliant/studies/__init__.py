"""Studies: reproducible numerical experiments that write figures, a Markdown table and JSON."""

from ._integrators import (
    cloth_stability,
    oscillator_orders,
    oscillator_stability_limit,
    run_integrator_study,
)

__all__ = ["cloth_stability", "oscillator_orders", "oscillator_stability_limit", "run_integrator_study"]
