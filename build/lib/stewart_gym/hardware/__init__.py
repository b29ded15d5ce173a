"""Hardware deployment: serial servo-controller protocols, safety layer, policy bundles, the control loop."""
