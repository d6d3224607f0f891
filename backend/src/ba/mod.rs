//! Bundle adjustment: the problem of paper 004's eq. 1 ([`problem`]), the reduced camera
//! system on faer's sparse Cholesky ([`reduced`]) and Levenberg-Marquardt with the Schur
//! complement ([`solver`]).

mod layout;
mod linearize;
pub mod problem;
pub mod reduced;
pub mod solver;
pub mod synthetic;

pub use problem::{PointEdge, PointVar, PoseEdge, PoseVar, Problem};
pub use solver::{solve, SolveReport, SolverOptions, Termination};
