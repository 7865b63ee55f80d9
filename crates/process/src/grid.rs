//! The map grid: [`bonnetlab_surface::Grid`], the project's one grid type, re-exported so that
//! `bonnetlab_process::Grid` and `crate::grid::Grid` name it.

pub use bonnetlab_surface::Grid;
