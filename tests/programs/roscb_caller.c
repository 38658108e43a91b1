/* A small caller of the libtracetools functions, as rcl and rclcpp call them: the raw test subject of the runner's
 * interposer (runner/run/roscb.c), tests/test_roscb.py.
 *
 * Built two ways: against tests/programs/roscb_minifake.c (a libtracetools.so that counts its calls; -DPUBLISH3 for
 * Jazzy's 3-argument rmw_publish and enabled_/do_ API, as the fake is built), or with no library at all (the
 * functions are weak: a program without libtracetools, where only a preload defines them).
 *
 * Modes (argv[1]):
 *   basic N        init calls (node, /rosout and /topic publishers, a subscription, a timer), then N timer callbacks
 *                  that publish and N subscription callbacks after a take
 *   nested         A inside B ended in order; then B started inside A and A ended first (B unterminated)
 *   deep           12 callbacks nested (8 kept, the others counted), ended innermost first
 *   orphan         an end with no start
 *   thread-exit    a thread named "quitter" starts a callback and exits inside it
 *   never-end      the main thread starts a callback and the program exits inside it
 *   fork           one callback, fork, the child runs 3 callbacks, the parent 2 more after it
 *   exec PROG ARG  one callback, then exec PROG ARG (the child's environment keeps the preload)
 *   many N         N callbacks on the main thread
 *   bench N        N empty callbacks (start + end), prints ns per pair
 *   timer N        a 1 ms timer as an executor runs it (clock_nanosleep to the next release, the executor's calls, a
 *                  callback that publishes), N releases; prints its wake-up latency: `latency_ns p50 p99 max`
 * It prints `calls <name> <n>` for every function the fake counted (when linked with it), then `done`.
 */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define WEAK __attribute__((weak))
WEAK void ros_trace_rcl_init(const void *);
WEAK void ros_trace_rcl_node_init(const void *, const void *, const char *, const char *);
WEAK void ros_trace_rcl_publisher_init(const void *, const void *, const void *, const char *, const size_t);
WEAK void ros_trace_rcl_subscription_init(const void *, const void *, const void *, const char *, const size_t);
WEAK void ros_trace_rclcpp_subscription_init(const void *, const void *);
WEAK void ros_trace_rclcpp_subscription_callback_added(const void *, const void *);
WEAK void ros_trace_rcl_timer_init(const void *, int64_t);
WEAK void ros_trace_rclcpp_timer_callback_added(const void *, const void *);
WEAK void ros_trace_rclcpp_timer_link_node(const void *, const void *);
WEAK void ros_trace_rclcpp_callback_register(const void *, const char *);
WEAK bool ros_trace_enabled_rclcpp_callback_register(void);
WEAK void ros_trace_do_rclcpp_callback_register(const void *, const char *);
WEAK void ros_trace_rclcpp_executor_get_next_ready(void);
WEAK void ros_trace_rclcpp_executor_wait_for_work(const int64_t);
WEAK void ros_trace_rclcpp_executor_execute(const void *);
WEAK void ros_trace_rmw_take(const void *, const void *, int64_t, const bool);
WEAK void ros_trace_rcl_publish(const void *, const void *);
#ifdef PUBLISH3
WEAK void ros_trace_rmw_publish(const void *, const void *, int64_t);
#else
WEAK void ros_trace_rmw_publish(const void *);
#endif
WEAK void ros_trace_callback_start(const void *, const bool);
WEAK void ros_trace_callback_end(const void *);
WEAK long fake_count(const char *);

#define CALL(name, ...)                                                                                                   \
    do {                                                                                                                  \
        if (ros_trace_##name) ros_trace_##name(__VA_ARGS__);                                                              \
    } while (0)

static char node, rmw_node, rosout, rmw_rosout, pub, rmw_pub, sub, rmw_sub, sub_obj, timer, msg;
static char cb_timer, cb_sub, cb_a, cb_b, cb_deep[12];

static int64_t realtime(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static void reg(const void *cb, const char *symbol) {
#ifdef PUBLISH3
    if (ros_trace_enabled_rclcpp_callback_register && ros_trace_enabled_rclcpp_callback_register())
        CALL(do_rclcpp_callback_register, cb, symbol);
#else
    CALL(rclcpp_callback_register, cb, symbol);
#endif
}

static void init(void) {
    char topic[] = "/topic", name[] = "minimal_publisher", symbol[] = "MinimalPublisher::timer_callback()";
    CALL(rcl_init, &node);
    CALL(rcl_node_init, &node, &rmw_node, name, "/");
    CALL(rcl_publisher_init, &rosout, &node, &rmw_rosout, "/rosout", 1000);
    CALL(rcl_publisher_init, &pub, &node, &rmw_pub, topic, 10);
    CALL(rcl_subscription_init, &sub, &node, &rmw_sub, topic, 10);
    CALL(rclcpp_subscription_init, &sub, &sub_obj);
    CALL(rclcpp_subscription_callback_added, &sub_obj, &cb_sub);
    reg(&cb_sub, "MinimalSubscriber::topic_callback(std_msgs::msg::String const&)");
    CALL(rcl_timer_init, &timer, 100000000);
    CALL(rclcpp_timer_callback_added, &timer, &cb_timer);
    memset(name, 'x', sizeof name - 1); /* the caller frees its strings after the call: the hook must have copied */
    reg(&cb_timer, symbol);
    memset(symbol, 'x', sizeof symbol - 1);
    memset(topic, 'x', sizeof topic - 1);
    CALL(rclcpp_timer_link_node, &timer, &node);
}

static void publish(int64_t stamp) {
    CALL(rcl_publish, &pub, &msg);
#ifdef PUBLISH3
    CALL(rmw_publish, &rmw_pub, &msg, stamp);
#else
    (void)stamp;
    CALL(rmw_publish, &msg);
#endif
}

static void one(const void *cb) {
    CALL(callback_start, cb, false);
    CALL(callback_end, cb);
}

static int by_value(const void *a, const void *b) {
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

static void timer_loop(long n) {
    int64_t *late = calloc((size_t)n, sizeof *late);
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    for (long i = 0; late && i < n; i++) {
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000) next.tv_sec++, next.tv_nsec -= 1000000000;
        CALL(rclcpp_executor_get_next_ready);
        CALL(rclcpp_executor_wait_for_work, 1000000);
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        struct timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now);
        late[i] = (now.tv_sec - next.tv_sec) * 1000000000LL + (now.tv_nsec - next.tv_nsec);
        CALL(rclcpp_executor_get_next_ready);
        CALL(rclcpp_executor_execute, &timer);
        CALL(callback_start, &cb_timer, false);
        publish(realtime());
        CALL(callback_end, &cb_timer);
    }
    if (!late) return;
    qsort(late, (size_t)n, sizeof *late, by_value);
    printf("latency_ns %lld %lld %lld\n", (long long)late[n / 2], (long long)late[n * 99 / 100], (long long)late[n - 1]);
    free(late);
}

static void *quitter(void *arg) {
    (void)arg;
    pthread_setname_np(pthread_self(), "quitter");
    CALL(callback_start, &cb_a, false);
    pthread_exit(NULL);
}

static void report(void) {
    static const char *names[] = {"rcl_init", "rcl_node_init", "rcl_publisher_init", "rcl_subscription_init",
                                  "rclcpp_subscription_init", "rclcpp_subscription_callback_added", "rcl_timer_init",
                                  "rclcpp_timer_callback_added", "rclcpp_timer_link_node", "rclcpp_callback_register",
                                  "do_rclcpp_callback_register", "rclcpp_executor_get_next_ready",
                                  "rclcpp_executor_wait_for_work", "rclcpp_executor_execute", "rmw_take", "rcl_publish",
                                  "rmw_publish", "rmw_publish_bad", "callback_start", "callback_end"};
    for (size_t i = 0; fake_count && i < sizeof names / sizeof names[0]; i++) printf("calls %s %ld\n", names[i], fake_count(names[i]));
    printf("done\n");
    fflush(stdout);
}

int main(int argc, char **argv) {
    const char *mode = argc > 1 ? argv[1] : "basic";
    long n = argc > 2 ? atol(argv[2]) : 10;
    init();
    if (!strcmp(mode, "basic")) {
        for (long i = 0; i < n; i++) {
            CALL(rclcpp_executor_get_next_ready);
            CALL(rclcpp_executor_wait_for_work, 100000000);
            usleep(200);
            CALL(rclcpp_executor_get_next_ready);
            CALL(rclcpp_executor_execute, &timer);
            CALL(callback_start, &cb_timer, false);
            int64_t stamp = realtime();
            publish(stamp);
            CALL(callback_end, &cb_timer);
            CALL(rclcpp_executor_execute, &sub);
            CALL(rmw_take, &rmw_sub, &msg, stamp, true);
            CALL(callback_start, &cb_sub, false);
            CALL(callback_end, &cb_sub);
            CALL(rmw_take, &rmw_sub, &msg, 0, false);
        }
        CALL(rcl_publish, &rosout, &msg); /* a log line: not recorded */
#ifdef PUBLISH3
        CALL(rmw_publish, &rmw_rosout, &msg, realtime());
#else
        CALL(rmw_publish, &msg);
#endif
    } else if (!strcmp(mode, "nested")) {
        CALL(callback_start, &cb_a, false);
        one(&cb_b);
        CALL(callback_end, &cb_a);
        CALL(callback_start, &cb_a, false);
        CALL(callback_start, &cb_b, false);
        CALL(callback_end, &cb_a);
    } else if (!strcmp(mode, "deep")) {
        for (int i = 0; i < 12; i++) CALL(callback_start, &cb_deep[i], false);
        for (int i = 11; i >= 0; i--) CALL(callback_end, &cb_deep[i]);
        one(&cb_a);
    } else if (!strcmp(mode, "orphan")) {
        CALL(callback_end, &cb_a);
        one(&cb_b);
    } else if (!strcmp(mode, "thread-exit")) {
        pthread_t t;
        pthread_create(&t, NULL, quitter, NULL);
        pthread_join(t, NULL);
    } else if (!strcmp(mode, "never-end")) {
        CALL(callback_start, &cb_a, false);
        report();
        return 0;
    } else if (!strcmp(mode, "fork")) {
        one(&cb_a);
        pid_t child = fork();
        if (child == 0) {
            for (int i = 0; i < 3; i++) one(&cb_b);
            _exit(0);
        }
        waitpid(child, NULL, 0);
        one(&cb_a);
        one(&cb_a);
    } else if (!strcmp(mode, "exec")) {
        one(&cb_a);
        fflush(stdout);
        execvp(argv[2], argv + 2);
        return 127;
    } else if (!strcmp(mode, "many")) {
        for (long i = 0; i < n; i++) one(&cb_a);
    } else if (!strcmp(mode, "timer")) {
        timer_loop(n);
    } else if (!strcmp(mode, "bench")) {
        struct timespec a, b;
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (long i = 0; i < n; i++) one(&cb_a);
        clock_gettime(CLOCK_MONOTONIC, &b);
        printf("ns_per_callback %.1f\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / (double)n);
    }
    report();
    return 0;
}
