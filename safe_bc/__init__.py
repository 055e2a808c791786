"""safe_bc: safety-focused behaviour cloning.

Importing the package registers its gymnasium environment ids, following gymnasium's
convention for third-party environments:

>>> import gymnasium as gym
>>> import safe_bc
>>> env = gym.make("safe_bc/RehabPathway-v0")
>>> env.close()

Without a prior import, ``gym.make("safe_bc:safe_bc/RehabPathway-v0")`` imports this
package first (the part before the colon). The ids are
``safe_bc/RehabPathway-v0`` (the rehabilitation pathway, safety costs in ``info``) and
``safe_bc/CarRacingFast-v3`` (CarRacing-v3 with a faster, pixel-identical renderer; wrap
it in :class:`safe_bc.tasks.carracing.wrapper.CarRacingSafety`, or use
:func:`safe_bc.tasks.make_env`, for the safety distances in ``info``), and
``safe_bc/CarRacingRaster-v3`` (an approximate, faster renderer, opt-in: see
:mod:`safe_bc.tasks.carracing.raster_render`). Registration imports gymnasium and numpy only
(no torch, no Ray).
"""

from safe_bc.moved import install as _install_moved
from safe_bc.tasks import ENV_IDS, register_envs
from safe_bc.version import __version__

_install_moved()
register_envs()

__all__ = ["ENV_IDS", "__version__", "load_recommender", "register_envs"]


def __getattr__(name: str):
    """``safe_bc.load_recommender`` (:func:`safe_bc.study.recommender.load_recommender`), imported
    on
    first use."""
    if name == "load_recommender":
        from safe_bc.study.recommender import load_recommender

        return load_recommender
    raise AttributeError(f"module 'safe_bc' has no attribute {name!r}")
