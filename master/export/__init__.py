"""Components exported as FMI 2.0 co-simulation FMUs (pythonfmu)."""
