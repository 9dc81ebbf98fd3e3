//! The file layer under the study folder ([`crate::export`]) and the raw
//! signal files ([`crate::rawsig`]): the storage error type ([`error`]),
//! durable file operations and torn-tail bookkeeping ([`fsutil`]), the
//! one-writer lock of a study folder ([`lock`]), and the
//! UTC timestamps written to every file ([`utc`]).
//!
//! A leaf: nothing here depends on the modules that write study files.
//! Public as [`crate::export::error`], [`crate::export::fsutil`] and
//! [`crate::export::utc`].

pub mod error;
pub mod fsutil;
pub mod lock;
pub mod utc;
