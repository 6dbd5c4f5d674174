"""``matplotlib.pyplot``, imported on first use with a non-interactive backend.

Plotting is optional in every package: importing pyplot at module level would
cost about half a second on every ``import gbo_envs`` and could open a GUI
backend in a worker process. Every figure in the project therefore asks
:func:`pyplot` for the module when it draws.
"""

from __future__ import annotations

__all__ = ["pyplot"]

#: Backends that draw off-screen; any other one is switched to Agg.
_HEADLESS_BACKENDS = ("agg", "module://matplotlib_inline.backend_inline")


def pyplot():
    """The ``matplotlib.pyplot`` module, on the Agg backend unless a headless one is already set.

    A notebook's inline backend is kept, so figures still show in Jupyter.

    Returns
    -------
    module
        ``matplotlib.pyplot``.
    """
    import matplotlib

    if matplotlib.get_backend().lower() not in _HEADLESS_BACKENDS:
        try:
            matplotlib.use("Agg")
        except Exception:  # pragma: no cover - an interactive backend already in use
            pass
    import matplotlib.pyplot as plt

    return plt
