"""racer.rollout_worker — see DESIGN.md for what this package owns."""
