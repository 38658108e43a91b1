/* A stub librclcpp.so for the stand-in node's `disabled` build (tests/rosfake.py).
 *
 * A ROS 2 installation built with TRACETOOLS_DISABLED has no libtracetools.so at all (tracetools is then an INTERFACE
 * target) while its nodes still load librclcpp.so: a program that maps librclcpp but no libtracetools is how the
 * runner tells "built with TRACETOOLS_DISABLED" from "not a ROS 2 program".  This library only has to be mapped.
 */
int rclcpp_stub_linked(void) { return 1; }
