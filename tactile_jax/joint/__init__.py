"""The joint 2-D fit of both probe pairs: one fixed-shape, compiled pipeline for ``fit`` and ``batch``."""
