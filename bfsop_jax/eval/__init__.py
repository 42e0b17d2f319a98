"""Evaluation: the navigation benchmark (Table I) and the solver comparison (Tables II/III)."""
