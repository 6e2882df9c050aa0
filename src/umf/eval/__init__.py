"""Evaluation: metrics, physics, relation accuracy and the per-person-index study."""
