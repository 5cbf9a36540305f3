"""Small helpers shared across the package (backend selection, validation)."""
