//! The one integration-test binary: modules per capability.

mod browser;
mod campaign;
mod cell_sim;
mod cli;
mod cockpit;
mod common;
mod frames;
mod identifiability;
mod paper;
mod paths;
mod practical;
mod quality;
mod realdata;
mod report;
mod reproduce;
mod robust;
mod safety;
mod serve;
mod setup;
mod sigma0;
mod significance;
mod store;
mod terminal;
mod validation;
mod zaber_motion;
