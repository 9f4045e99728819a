"""The bus attacks of docs/safety.md § 5a on real-time runs across processes, and their
measured outcomes: the attacking node (:mod:`~tools.safety.attacks.attacker`, its process
:mod:`~tools.safety.attacks.__main__`), the runs and a campaign of them
(:mod:`~tools.safety.attacks.runs`), their figures and verdict
(:mod:`~tools.safety.attacks.analysis`), and what authentication costs per tick
(:mod:`~tools.safety.attacks.cost`).  ``wheelchair-hil attack`` (tools/cli/attack.py) prints
them."""
