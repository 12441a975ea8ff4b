"""Browser apps (viser): one module per paper's interactive system, plus shared helpers.

``fxspace studio RUN_DIR|CONFIG`` picks the app from the run's experiment. viser is an
optional extra (``pip install -e ".[viewer]"``); it is imported only when an app starts.
"""
