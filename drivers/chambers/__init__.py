"""Thermal chambers: Watlow F4T (Modbus TCP/RTU) and Espec P-300 (text protocol), one Chamber interface."""
