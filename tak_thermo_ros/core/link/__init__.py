"""The correction link: the model per sensor, its correction (vectorised, per sample, by blocks), the node's logic."""
