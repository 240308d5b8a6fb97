"""The experiment's files: atomic writes and staging folders, tables, figures, the animation."""
