"""Learned policies (imitation) as ManiSkill agents: ``agent.ImitationPolicy.get_action(obs)``,
the networks they load (``networks``), the data they read (``data``) and the ``e2e-*`` /
``cgn-imit-*`` methods of ``fetchbench eval`` (``deploy``). Training: ``baselines/imitation/``."""
