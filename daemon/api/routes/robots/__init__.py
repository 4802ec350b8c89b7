"""The robot and its sub-resources, one router module per resource (this package module
imports nothing)."""
