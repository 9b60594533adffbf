"""Families of CMRTs along one task parameter (paper sections 5.3 and 6.2, Table 2), by
concern; pure: no process pool, no files, no web, queue or database code.

    optim.family.spec     the request (`FamilySpec`, `parse_family`) and each member's spec
    optim.family.plan     the plan: a DAG of runs (`PlannedRun`), which are ready, where each
                          starts (`run_start`), the members and the interpolation probes
    optim.family.checks   the checks of a finished family (Table 2 rows, strategy switches)
    optim.family.report   the family's document and its markdown tables
    optim.family.machine  the one state machine: a family's next actions from its state
                          (`next_actions`), carried out by `optim.family_run` (this process)
                          and `worker.family` (the service's jobs)
"""
