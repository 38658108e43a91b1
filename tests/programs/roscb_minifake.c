/* A minimal libtracetools.so for the interposer's raw tests (tests/test_roscb.py): every function the runner's
 * interposer defines, each counting its calls (fake_count(name)).  -DPUBLISH3 builds Jazzy's shape: the enabled_/do_
 * pair for the register (enabled only with FAKE_SESSION set, a simulated `ros2 trace`) and a 3-argument rmw_publish
 * whose arguments it checks (a wrong arity forwarded shows as a wrong timestamp, counted in rmw_publish_bad).
 * The full per-distro fake, generated from the vendored headers, is tests/rosfake.py's.
 */
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define COUNTED(X)                                                                                                        \
    X(rcl_init)                                                                                                           \
    X(rcl_node_init)                                                                                                      \
    X(rcl_publisher_init)                                                                                                 \
    X(rcl_subscription_init)                                                                                              \
    X(rclcpp_subscription_init)                                                                                           \
    X(rclcpp_subscription_callback_added)                                                                                 \
    X(rcl_timer_init)                                                                                                     \
    X(rclcpp_timer_callback_added)                                                                                        \
    X(rclcpp_timer_link_node)                                                                                             \
    X(rclcpp_callback_register)                                                                                           \
    X(do_rclcpp_callback_register)                                                                                        \
    X(rclcpp_executor_get_next_ready)                                                                                     \
    X(rclcpp_executor_wait_for_work)                                                                                      \
    X(rclcpp_executor_execute)                                                                                            \
    X(rmw_take)                                                                                                           \
    X(rcl_publish)                                                                                                        \
    X(rmw_publish)                                                                                                        \
    X(rmw_publish_bad)                                                                                                    \
    X(callback_start)                                                                                                     \
    X(callback_end)

#define INDEX(name) I_##name,
enum { COUNTED(INDEX) N_COUNTED };
#define NAME(name) #name,
static const char *names[] = {COUNTED(NAME)};
static long counts[N_COUNTED];

long fake_count(const char *name) {
    for (int i = 0; i < N_COUNTED; i++)
        if (!strcmp(names[i], name)) return __atomic_load_n(&counts[i], __ATOMIC_RELAXED);
    return -1;
}

#define BUMP(name) __atomic_fetch_add(&counts[I_##name], 1, __ATOMIC_RELAXED)

void ros_trace_rcl_init(const void *c) { BUMP(rcl_init); }
void ros_trace_rcl_node_init(const void *a, const void *b, const char *n, const char *s) { BUMP(rcl_node_init); }
void ros_trace_rcl_publisher_init(const void *a, const void *b, const void *c, const char *t, const size_t d) { BUMP(rcl_publisher_init); }
void ros_trace_rcl_subscription_init(const void *a, const void *b, const void *c, const char *t, const size_t d) {
    BUMP(rcl_subscription_init);
}
void ros_trace_rclcpp_subscription_init(const void *a, const void *b) { BUMP(rclcpp_subscription_init); }
void ros_trace_rclcpp_subscription_callback_added(const void *a, const void *b) { BUMP(rclcpp_subscription_callback_added); }
void ros_trace_rcl_timer_init(const void *a, int64_t p) { BUMP(rcl_timer_init); }
void ros_trace_rclcpp_timer_callback_added(const void *a, const void *b) { BUMP(rclcpp_timer_callback_added); }
void ros_trace_rclcpp_timer_link_node(const void *a, const void *b) { BUMP(rclcpp_timer_link_node); }
void ros_trace_rclcpp_callback_register(const void *a, const char *s) { BUMP(rclcpp_callback_register); }
void ros_trace_rclcpp_executor_get_next_ready(void) { BUMP(rclcpp_executor_get_next_ready); }
void ros_trace_rclcpp_executor_wait_for_work(const int64_t t) { BUMP(rclcpp_executor_wait_for_work); }
void ros_trace_rclcpp_executor_execute(const void *h) { BUMP(rclcpp_executor_execute); }
void ros_trace_rmw_take(const void *a, const void *m, int64_t ts, const bool taken) { BUMP(rmw_take); }
void ros_trace_rcl_publish(const void *a, const void *m) { BUMP(rcl_publish); }
void ros_trace_callback_start(const void *cb, const bool intra) { BUMP(callback_start); }
void ros_trace_callback_end(const void *cb) { BUMP(callback_end); }
bool ros_trace_compile_status(void) { return false; }

#ifdef PUBLISH3
bool ros_trace_enabled_callback_start(void) { return getenv("FAKE_SESSION") != NULL; }
bool ros_trace_enabled_rclcpp_callback_register(void) { return getenv("FAKE_SESSION") != NULL; }
void ros_trace_do_rclcpp_callback_register(const void *a, const char *s) { BUMP(do_rclcpp_callback_register); }
void ros_trace_rmw_publish(const void *pub, const void *m, int64_t ts) {
    BUMP(rmw_publish);
    if (!pub || !m || ts < 1000000000000000000LL) BUMP(rmw_publish_bad); /* a realtime stamp is after 2001 */
}
#else
void ros_trace_rmw_publish(const void *m) {
    BUMP(rmw_publish);
    if (!m) BUMP(rmw_publish_bad);
}
#endif
