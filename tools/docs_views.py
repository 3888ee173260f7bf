"""Generated blocks of the docs: view name -> function(recording) -> Markdown text (tools/docs_check.py)."""
VIEWS = {}
