"""The digitised track database (SQLite) and its geometry."""
