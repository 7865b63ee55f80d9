//! Reading and writing surface maps: every format a ZYGO NV7300 (MetroPro / Mx) exports, plus
//! CSV and EXR grids; and atomic output files (temporary file + rename).
