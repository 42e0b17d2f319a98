"""Navigation strategies (FBE, BFS-Global, TFL-Reactive, BF-SOP), the one rollout, and the
episode recorder behind the GIFs (:mod:`bfsop_jax.agents.record`)."""

from bfsop_jax.agents.bfs_global import BFSGlobal, BFSGlobalConfig
from bfsop_jax.agents.bfsop import BFSOP, BFSOPConfig
from bfsop_jax.agents.fbe import FBE, FBEConfig, FBEMemory
from bfsop_jax.agents.planners import NearestNeighbourPlanner, TransformerPlanner, VNSPlanner
from bfsop_jax.agents.record import EpisodeFrames, EpisodeRecorder, record_episode
from bfsop_jax.agents.rollout import (
    Decision,
    Strategy,
    Trajectory,
    continue_rollout,
    explore_decision,
    max_macro_steps,
    rollout,
)
from bfsop_jax.agents.tfl_reactive import TFLReactive, TFLReactiveConfig

__all__ = [
    "BFSGlobal",
    "BFSGlobalConfig",
    "BFSOP",
    "BFSOPConfig",
    "Decision",
    "EpisodeFrames",
    "EpisodeRecorder",
    "FBE",
    "FBEConfig",
    "FBEMemory",
    "NearestNeighbourPlanner",
    "Strategy",
    "TFLReactive",
    "TFLReactiveConfig",
    "Trajectory",
    "TransformerPlanner",
    "VNSPlanner",
    "continue_rollout",
    "explore_decision",
    "max_macro_steps",
    "record_episode",
    "rollout",
]
