"""The drift's release distance: 5 default demonstration episodes at each of 0, 3, 4.5, 6
and 10 px (the committed ``results/demos/release_sweep.md``, behind the default of 6 px).

Run: ``python -m scripts.release_sweep tune_jobs/sweeps/drift_release.py``
(about 2 minutes on 2 cores). Drawn by the default renderer (raster), which draws the
demonstrations; the table before it was drawn by the exact renderer (the default then).
"""

from pathlib import Path

from safe_bc.rollout.release_sweep import ReleaseSweep

SWEEP = ReleaseSweep(releases=(0.0, 3.0, 4.5, 6.0, 10.0), episodes=5, out=Path("results/demos"))
