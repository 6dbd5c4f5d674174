"""How a tuning run shows itself: the env's display name and the progress bar (loop, RL pre-training)."""

from __future__ import annotations

__all__ = ["env_id", "progress_bar"]


def env_id(env) -> str:
    """The registered id of an env (wrappers allowed), else its class name."""
    spec = getattr(env, "spec", None)
    return spec.id if spec is not None else type(env.unwrapped).__name__


class _NoBar:
    """Stands in for a disabled bar: a disabled tqdm still allocates a multiprocessing lock."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(total: int, desc: str, enabled: bool, initial: int = 0, unit: str = "exp"):
    """A tqdm progress bar of ``total`` steps, or a no-op stand-in when ``enabled`` is false."""
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit)
