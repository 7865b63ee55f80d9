//! Closing the loop with measured data: registration, residual, diagnosis, an effect library
//! with hold-out selection, and a generator of synthetic measured runs.
