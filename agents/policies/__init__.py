"""The drivers and the parts of a driving policy: what acts, what it sees, what a policy file records.

* scripted drivers on the simulator's true state: :mod:`agents.policies.expert` (the headway driver, the teacher of
  imitation) and :mod:`agents.policies.lookahead` (its rollout improvement);
* the decision interval (:mod:`agents.policies.decision`: one decision every ``k`` env steps) and the radar safety
  shield (:mod:`agents.policies.shield`: vetoes the meta-actions the radar points show to be unsafe);
* the network's point-set feature extractor (:mod:`agents.policies.features`) and the privileged critic's input
  (:mod:`agents.policies.privileged`: the true road state as one vector);
* a policy file: its record (:mod:`agents.policies.policy_record`: env id, env kwargs, decision interval, shield)
  and a trained RLlib checkpoint as a policy (:mod:`agents.policies.rllib_policy`).

These modules import nothing of :mod:`agents.algos` (the training side) nor of the entry modules.
"""
