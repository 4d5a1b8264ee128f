"""Where jaxcart's own training time goes: the update against the core's matmul rates
(``roofline``), the update's parts (``update``), cold compile (``compile_time``), seed numerics
against batch width (``seed_width``), the phases of one iteration (``profile_step``), progress
reports between chunks (``chunk_overhead``) and devices against processes (``scaling``)."""
