"""bfsop_jax: JAX-native, batched BF-SOP (budgeted multi-object navigation with a
Set Orienteering planner distilled into a Strategic Transformer)."""

__version__ = "0.1.0"
