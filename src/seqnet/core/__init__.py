"""Infrastructure every stage shares: errors, configs, atomic files, ownership and locks, progress, provenance."""
