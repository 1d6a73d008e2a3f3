"""Command-line adapters: argument parsing and printing only; the work is done elsewhere."""
