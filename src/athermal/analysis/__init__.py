"""The analyses of a configuration: observables (stress, fabric, rattlers), linear-response
moduli and stability, vibrational modes, force statistics and power-law fits."""
