//! TODO(module owner): see crate docs.
