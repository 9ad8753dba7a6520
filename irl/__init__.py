"""Tabular MDPs, gridworlds, planning, demonstrations and constraint learning (MESC-IRL).

``irl`` supplies the attributes that an MDFT orchestrator deliberates over: the
Q-values and policies of a nominal MDP and of one whose soft constraints were
learned from demonstrations. It does not depend on :mod:`mdft`.
"""
