"""Running episodes: one episode and lockstep batches (``episode``), collecting
demonstrations (``collect``), evaluating agents on tracks (``evaluate``, ``config``), and the
drift's release-distance sweep (``release_sweep``). No Ray here: ``safe_bc.distributed`` fans
these out."""

from safe_bc.moved import forward

__getattr__ = forward(__name__, "safe_bc.rollout.episode")
