/* The built-in functions every board has: board_gen.c starts its function table with
 * BUILTIN_FUNCTIONS.  Their handlers are runtime.c's, but a2jHostMap's, which is timing.c's:
 * the table is where the two meet, so that neither calls into the other. */
#ifndef J2A_BUILTINS_H
#define J2A_BUILTINS_H
#include "runtime.h"
#include "timing.h"

uint8_t get_mapping(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t get_debug(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t echo(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t sif_count(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
extern const blob_t mapping_blob, board_properties_blob, board_transds_blob;
extern const char n_get_mapping[], n_many[], n_get_properties[], n_debug[], n_echo[],
    n_echo_many[], n_get_mapping_many[], n_get_transds[], n_clock[], n_host_map[], n_sif_count[];
#if ML_TIMING
#define BUILTIN_COUNT 11
#define BUILTIN_HOST_MAP , {n_host_map, KIND_PLAIN, host_map_fn, 0}
#else /* (no host map without host time: a board that has no a2jHostMap runs on its own clock) */
#define BUILTIN_COUNT 10
#define BUILTIN_HOST_MAP
#endif
#define BUILTIN_FUNCTIONS                                                                      \
    {n_get_mapping, KIND_PLAIN, get_mapping, 0}, {n_many, KIND_PLAIN, 0, 0},                   \
        {n_get_properties, KIND_BLOB, 0, &board_properties_blob},                             \
        {n_debug, KIND_PLAIN, get_debug, 0}, {n_echo, KIND_PLAIN, echo, 0},                    \
        {n_echo_many, KIND_ECHO_MANY, 0, 0}, {n_get_mapping_many, KIND_BLOB, 0, &mapping_blob}, \
        {n_get_transds, KIND_BLOB, 0, &board_transds_blob}, {n_clock, KIND_CLOCK, 0, 0}        \
        BUILTIN_HOST_MAP, {n_sif_count, KIND_PLAIN, sif_count, 0}

#endif
