//! Fixed-point (spot) polishing sweeps: per-spot TIF metrics, per-bonnet trends across a swept
//! factor, and the bonnet TIF model fitted to the spots.
