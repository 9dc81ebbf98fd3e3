//! End-to-end tests of kilotouch across crates.
//!
//! Every file in this directory is a module of this one test binary
//! (`autotests = false` in Cargo.toml): one link instead of one per file.
//! Run one file's tests with `cargo test -p kilotouch-e2e --test integration FILE::`.
//! The workspace test `every_test_file_is_compiled` (tests/workspace.rs)
//! fails if a file here is not declared below.

mod closed_loop;
mod equivalence;
mod module_graph;
mod scipy_crosscheck;
mod workspace;
