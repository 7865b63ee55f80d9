//! Power spectral densities of surface maps (1-D along X and Y, 2-D, radial), band-limited RMS
//! and the ripple check at the raster's grating spacing. Conventions: `shared/spec/metrology.md`.
