//! The paper's systems and the `spark` command-line program.
