"""Universal Robots e-Series: RTDE (port 30004), the Dashboard Server (port 29999) and the UR
robot driver (issue 31)."""
