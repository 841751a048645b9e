"""A live digital twin: ``pliant view SCENE`` runs the simulation in the browser, where a drag on the object
pulls it (a capped spring to the cursor, through the simulation, with every solver), sliders change its
material while it moves, and a button records the session (``.npz`` + ``.mp4``).

:class:`LiveSession` is the simulation side (no browser: tests drive it as the mouse does);
:func:`serve_live` serves it with viser (``pip install 'pliant[viewer]'``).
"""

from ._server import LiveViewer, serve_live, splat_arrays
from ._session import LiveParameter, LiveSession, live_parameters, scene_trajectory_meta, write_parameter

__all__ = [
    "LiveParameter",
    "LiveSession",
    "LiveViewer",
    "live_parameters",
    "scene_trajectory_meta",
    "serve_live",
    "splat_arrays",
    "write_parameter",
]
