"""Running the network: the launcher (``skynet up``/``mission``), its link topology and impairment grammar,
scripted faults, the process group and its restart policy, and the trust mode it starts the network in."""
