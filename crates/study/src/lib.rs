//! kilotouch-study: see README.md. Implemented in a later issue.
