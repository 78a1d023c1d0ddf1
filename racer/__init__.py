"""racer command line (thin: each command parses options and calls one function)."""
