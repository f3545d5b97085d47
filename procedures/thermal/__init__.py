"""Thermal control: chamber profiles, strategies and the control loop the thermal step types
drive."""
