"""glad-payload: the Global-Local MAV Detector (GLAD) as an onboard service."""

__version__ = "0.1.0"
