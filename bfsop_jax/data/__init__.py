"""Teacher-labelled datasets: generation from training houses and resumable shards."""

from bfsop_jax.data.generate import DataConfig, generate_dataset
from bfsop_jax.data.shards import ShardStore, merge_datasets

__all__ = ["DataConfig", "ShardStore", "generate_dataset", "merge_datasets"]
