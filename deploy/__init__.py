"""racer.deploy — see DESIGN.md for what this package owns."""
