"""racer.model_store — see DESIGN.md for what this package owns."""
