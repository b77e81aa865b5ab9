"""Global lens design search from a specification (issue #36)."""
