"""Interface modules: sensor senders and the train/sensor simulator."""
