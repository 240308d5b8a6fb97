"""The reach: the free arm reaching to a seen goal (docs/reach.md): the task (``task.py``), its folder
(``publish.py``) and figures."""
