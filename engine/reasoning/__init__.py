"""Reasoning: what the plant's rules say must exist.

``reason`` runs the rules ontology over a validated plant, with the fast forward-chaining engine
(``rules_fast``) or owlready2's HermiT + Pellet (``rules_owlready``), both reading the rules from
``rules_tbox``; ``rules_errors`` holds the typed errors a user can meet there; ``explain`` answers
"why must this broker, topic or bridge exist?" from the fast engine's own derivations.
"""
