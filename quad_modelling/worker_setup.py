"""What a local Dask cluster's worker (``--jobs``) does at its start, as dask's preload (:data:`quad_modelling.fanout.WORKER_PRELOAD`).

SIGINT ignored: a Ctrl-C of the process group is the command's to act on (it closes the cluster); a worker would
print a KeyboardInterrupt traceback each. The worker's main thread imports a preload, so the handler may be set.
"""

import signal
import threading

if threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGINT, signal.SIG_IGN)
