"""The line laser beside the camera: pulsed by the co-MCU (its client, comcu.py) in step with the
camera's exposures (synced.py, with the synchronisation controller of device/sync), behind one
interface (base.py)."""
