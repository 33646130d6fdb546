"""The virtual tester: simulated instruments that serve the real wire protocols on loopback sockets.

Physics comes in through :class:`drivers.virtual.physics.CellPhysics`; battlab provides the DFN-backed one,
:class:`drivers.virtual.physics.EquivalentCircuitCell` is a stand-in. :class:`drivers.virtual.lab.VirtualLab`
puts a cycler (SCPI), a chamber (Modbus TCP and RTU as a Watlow F4T, text as an Espec P-300) and a clock
together.
"""
