//! Identification's solver: the crate's least-squares core ([`crate::lsq`]) with its default
//! [`Options`] (Moré-scaled Levenberg–Marquardt, Nielsen damping, geodesic acceleration).

pub use crate::lsq::{
    gradient_cosine, solve, solve_from, Linearization, Options, Problem, Solution, Termination,
    DEFAULT_MAX_ITERATIONS,
};
