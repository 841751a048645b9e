"""Fitting a simulation to observed motion (real-to-sim), the way PhysTwin builds digital twins.

PhysTwin (Jiang et al., ``Jianghanxiao/PhysTwin``) fits a spring-mass twin to tracked points in two stages:
CMA-ES over a few global and topology parameters (forward runs only), then Adam on per-spring log stiffness
with gradients over one-frame horizons. pliant follows that method with its own code, on any scene file:

- observations: :class:`pliant.io.Observations` (NPZ: ``t``, ``points``, ``visible``, ``particle``,
  ``controls``, ``cloud``/``cloud_count``);
- losses (Warp kernels, differentiable): smooth-L1 tracking, one-sided Chamfer, acceleration regulariser;
- parameters: :data:`GLOBAL` (scene values, stage 1) and :data:`PER_ELEMENT` (log-scale factors on model or
  constraint arrays, stage 2);
- :func:`cmaes`, :func:`gradient_stage` and :func:`fit` (both stages and the outputs of ``pliant fit``);
- :func:`observe`: synthetic observations from a simulation (``pliant observe``);
- photometric system identification from camera videos alone: :class:`PhotometricProblem` (used by
  :func:`fit` when the observations carry ``images``), :func:`refine_globals` (image gradients through the
  rollout) and :func:`observe_images` (synthetic videos, ``pliant observe --cameras``).

Example::

    cfg = pl.scene.load_scene("fit_rope")
    obs = pl.io.Observations.load("obs.npz")
    report = pl.fit.fit(cfg, obs, "out/fit", params=["stiffness", "damping"])
"""

from __future__ import annotations

from ._cmaes import PENALTY, StageResult, cmaes, evaluate
from ._explain import FitWarning
from ._gradient import Smoothness, gradient_stage
from ._identify import describe as describe_identifiability
from ._losses import acceleration_loss, chamfer_loss, track_errors, track_loss
from ._mass import MassChoice, choose_mass_distribution
from ._models import MODELS, compare_models, models_table
from ._observe import observe
from ._observe_images import observe_images
from ._params import (
    DEFAULTS,
    GLOBAL,
    PER_ELEMENT,
    Bound,
    FitError,
    GlobalParam,
    apply_globals,
    default_params,
)
from ._photometric import PhotometricProblem, refine_globals
from ._problem import Problem
from ._resume import CHECKPOINT_FILE, read_checkpoint
from ._run import PARAMS_FILE, fit, fitted_scene
from ._toml import dumps as toml_dumps
from ._toml import scene_toml

__all__ = [
    "CHECKPOINT_FILE",
    "FitWarning",
    "DEFAULTS",
    "GLOBAL",
    "MODELS",
    "PARAMS_FILE",
    "PENALTY",
    "PER_ELEMENT",
    "Bound",
    "FitError",
    "GlobalParam",
    "MassChoice",
    "PhotometricProblem",
    "Problem",
    "Smoothness",
    "StageResult",
    "acceleration_loss",
    "apply_globals",
    "chamfer_loss",
    "choose_mass_distribution",
    "cmaes",
    "compare_models",
    "default_params",
    "describe_identifiability",
    "evaluate",
    "fit",
    "fitted_scene",
    "models_table",
    "gradient_stage",
    "observe",
    "observe_images",
    "read_checkpoint",
    "refine_globals",
    "scene_toml",
    "toml_dumps",
    "track_errors",
    "track_loss",
]
