"""One module per task; each defines a ManipulationEnv subclass."""
