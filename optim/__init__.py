"""Numerics of the CMRT service: no web, queue or database code.

Modules:
    optim.spline       the CMRT spline and its [0, 1]^d parameter encoding
    optim.cmaes        CMA-ES wrapper (own RNG, picklable) and the paper's stopping rules
    optim.executors    serial / process-pool evaluation of candidate batches
    optim.objective    the simulation objective (one Simulator per process)
    optim.loop         the one optimisation loop (CLI and service): step, stop rules, final pair
    optim.run          `cmrt optimize`: the loop with atomic checkpoint files and resume
    optim.result       OptimizationResult (JSON file format)
    optim.pca          PCA basis of a family of results, reduced-space search
    optim.interpolate  interpolation of results along a task parameter
    optim.superpose    superposition of time-shifted CMRTs
    optim.family       families along a task parameter: the request (.spec), the plan of runs
                       (.plan), Table 2 checks (.checks), the document (.report) and the one
                       state machine both drivers run (.machine)
    optim.family_run   the command line's family driver: this process, one shared pool,
                       resumable
    optim.errors       domain exceptions
"""
