"""racer.common — see DESIGN.md for what this package owns."""
