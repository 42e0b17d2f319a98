"""The Strategic Transformer: features, the network (Flax NNX) and SOP decoding.

Design: docs/design.md §8.1.
"""

from bfsop_jax.model.decode import (
    DecodeTrace,
    TeacherForcing,
    allowed_next,
    decode,
    greedy_decode,
    plan_value,
    sample_decode,
    teacher_forced_logits,
)
from bfsop_jax.model.features import (
    NodeFeatures,
    node_features,
    step_features,
    symmetric_features,
)
from bfsop_jax.model.transformer import DECODERS, ModelConfig, StrategicTransformer

__all__ = [
    "DECODERS",
    "DecodeTrace",
    "ModelConfig",
    "NodeFeatures",
    "StrategicTransformer",
    "TeacherForcing",
    "allowed_next",
    "decode",
    "greedy_decode",
    "node_features",
    "plan_value",
    "sample_decode",
    "step_features",
    "symmetric_features",
    "teacher_forced_logits",
]
