/*
 * Minimal assertion kit for the firmware host tests. Each executable prints
 * "N passed, N failed" and exits non-zero on any failure, which is what ctest
 * (and CI reading its output) acts on.
 */
#ifndef TESTKIT_H
#define TESTKIT_H

#include <stdio.h>

static unsigned tk_passed;
static unsigned tk_failed;

#define TK_CHECK(cond, ...)                                                  \
    do {                                                                     \
        if (cond) {                                                          \
            tk_passed++;                                                     \
        } else {                                                             \
            tk_failed++;                                                     \
            fprintf(stderr, "FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                    \
            fputc('\n', stderr);                                             \
        }                                                                    \
    } while (0)

#define TK_CHECK_EQ_INT(actual, expected, what)                              \
    TK_CHECK((long long)(actual) == (long long)(expected), "%s: got %lld, want %lld", \
             (what), (long long)(actual), (long long)(expected))

static inline int tk_report(const char *suite)
{
    printf("%s: %u passed, %u failed\n", suite, tk_passed, tk_failed);
    return tk_failed == 0u ? 0 : 1;
}

#endif /* TESTKIT_H */
