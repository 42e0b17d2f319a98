"""Figures, all in one place and in one style (:mod:`bfsop_jax.viz.style`), by subject:

* :mod:`~bfsop_jax.viz.world`: a house, a belief map;
* :mod:`~bfsop_jax.viz.trajectories`: executed trajectories, alone or side by side;
* :mod:`~bfsop_jax.viz.tours`: SOP tours of several planners, the decoder's distance mass;
* :mod:`~bfsop_jax.viz.training`: the training curve, DAgger rounds;
* :mod:`~bfsop_jax.viz.evaluation`: PPL per method and per category, the sweep chart,
  models side by side (reward against latency), paired differences (forest plot);
* :mod:`~bfsop_jax.viz.animation`: an episode as a GIF (belief map, path, tour ahead,
  verified targets, budget bar) from recorded frames (plain NumPy arrays).

Each ``plot_*`` function draws one picture of one thing and saves it as a PNG when given a
path (written atomically); :func:`animate_episode` writes a GIF the same way. The package
imports no agent, training or evaluation code (those import it; recorded frames come in
as NumPy arrays), and draws with the Agg backend, so it works without a display.
"""

from bfsop_jax.viz.animation import animate_episode
from bfsop_jax.viz.evaluation import (
    plot_category_ppl,
    plot_model_comparison,
    plot_paired_differences,
    plot_ppl,
    plot_sweep,
)
from bfsop_jax.viz.tours import plot_distance_mass, plot_tour_comparison
from bfsop_jax.viz.training import plot_dagger, plot_rl, plot_training_curve
from bfsop_jax.viz.trajectories import plot_trajectories_side_by_side, plot_trajectory
from bfsop_jax.viz.world import plot_belief, plot_house

__all__ = [
    "animate_episode",
    "plot_belief",
    "plot_category_ppl",
    "plot_dagger",
    "plot_rl",
    "plot_distance_mass",
    "plot_house",
    "plot_model_comparison",
    "plot_paired_differences",
    "plot_ppl",
    "plot_sweep",
    "plot_tour_comparison",
    "plot_training_curve",
    "plot_trajectories_side_by_side",
    "plot_trajectory",
]
