"""racer.trainer — see DESIGN.md for what this package owns."""
