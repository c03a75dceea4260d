/* The world's batches of ticks (world.c): the control line a world beside the rig speaks
 * (virtual/world_avr.py), one line each way a batch of ticks. */
#ifndef RIG_WORLD_H
#define RIG_WORLD_H
#include "rig.h"

/* the longest control line the rig takes (a batch's line), less its newline; a longer one is
 * refused whole (world_avr.py's RIG_LINE_MAX) */
#define RIG_LINE_MAX 16383

/* rig_sim's dispatcher: `line` run by the part that takes it, its answer printed */
typedef void (*rig_run_t)(const char *line);

void world_init(rig_run_t run);
/* whether `line` is the world's `tick ...` line (its refusals are "error tick: ...") */
int world_is_tick(const char *line);
/* the `tick ...` line (rig_command_t) */
int world_command(const char *line);
/* at each look at the simulated time: the batch's ticks whose time has come */
void world_watch(void);
#endif
