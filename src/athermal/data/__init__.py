"""Reference configurations shipped with athermal (see README.md in this folder)."""
