//! The polishing process: tool influence functions, raster paths and their kinematics,
//! dwell-time solvers and removal simulation (fast FFT and exact time-domain deposition).
