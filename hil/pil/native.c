/* hil.pil's block and check hooks in C, handed to Unicorn through its C API (hil/pil/native.py).

   The cycle accounting is hil.pil.core's Core._on_block, line for line: a block's cost comes from a
   table Python fills when it first decodes the block (an open-addressing hash map by address); a
   block this table does not know, or knows with another size, or marks for Python (a fault found
   by decoding) goes to Python's hook (slow_block), which decodes, charges and inserts it. The
   per-address checks of divides, LDRD/STRD and LDM/STM are Core._on_check's tests; a check that
   fails goes to Python (slow_check), which names the fault. Nothing here allocates on the hot path. */

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(_WIN32)
#define PIL_EXPORT __declspec(dllexport)
#else
#define PIL_EXPORT __attribute__((visibility("default")))
#endif

#define PIL_SOFT_FLOAT_MAX 256

typedef int (*pil_uc_emu_stop)(void *uc);
typedef int (*pil_uc_reg_read)(void *uc, int regid, void *value);
typedef void (*pil_slow_block)(uint64_t address, uint32_t size);
typedef void (*pil_slow_check)(uint64_t address, uint32_t size, uint32_t index);

typedef struct {
    uint32_t key;         /* address + 1 (Thumb addresses are even, below 2^32); 0: an empty slot */
    uint32_t size;        /* bytes of the translated block the entry was decoded from */
    uint32_t cycles;      /* Block.cycles: its cost when the branch at its end is not taken */
    uint32_t count;       /* Block.count: instructions */
    uint32_t taken_extra; /* Block.taken_extra */
    uint32_t entry_extra; /* Block.entry_extra */
    int32_t softfloat;    /* the soft-float routine it is the entry of (an index), or -1 */
    uint32_t flags;       /* PIL_FP, PIL_PYTHON */
} pil_block;

#define PIL_FP 1u     /* holds an FP instruction (Block.fp) */
#define PIL_PYTHON 2u /* always Python's hook (Block.fault) */

typedef struct {
    /* the counters and the running call, all int64 (Python reads and writes them as one array): Python
       writes them before uc_emu_start and reads them after */
    int64_t cycles;
    int64_t instructions;
    int64_t stop_at;          /* Core._stop_at rounded up (a cycle count is an integer) */
    int64_t prev_fallthrough; /* Core._prev.fallthrough (-1: the first block of a call) */
    int64_t prev_taken_extra; /* Core._prev.taken_extra */
    int64_t charge, uses_fp, fp_frame, lazy_stacked; /* the running _Frame's */
    int64_t softfloat_dirty;  /* a soft-float count changed since Python last read them */
    int64_t lazy_fp_stacking; /* CycleTable.lazy_fp_stacking */
    /* the framework's code (Core.load_framework_code): a call that reaches it (an interrupt returning
       into the output read its `then` named, or the output read itself) is in its tail from there:
       the cycles and instructions at that point are kept (Core gives back what the tail ran), and
       the tail is not paused, only stopped at the call's hang budget */
    int64_t framework_lo, framework_hi;
    int64_t tail_cycles;       /* -1: not in the tail */
    int64_t tail_instructions;
    int64_t hang_at;           /* the running call's budget (Core._frame.hang_at) */
    int64_t softfloat_counts[PIL_SOFT_FLOAT_MAX];
    /* the host's functions */
    pil_uc_emu_stop emu_stop;
    pil_uc_reg_read reg_read;
    pil_slow_block slow_block;
    pil_slow_check slow_check;
    /* the block table */
    pil_block *table;
    uint64_t mask;
    uint64_t used;
} pil_state;

typedef struct {
    pil_state *state;
    uint32_t kind;   /* 0: a divide (the divisor is zero); 1: alignment of register + offset [+ index] */
    int32_t reg;     /* Unicorn's register number */
    uint32_t offset;
    uint32_t index;  /* which check, for Python */
    int32_t index_reg; /* Unicorn's number of the index register, 0 when none */
    uint32_t mask;   /* the address bits that must be zero: 3 a word, 1 a halfword */
} pil_check;

static inline uint64_t pil_slot(uint32_t key, uint64_t mask)
{
    return (uint64_t)((key >> 1) * 2654435761u) & mask;
}

static pil_block *pil_find(const pil_state *s, uint64_t address)
{
    uint32_t key = (uint32_t)address + 1u;
    uint64_t k = pil_slot(key, s->mask);
    for (;;) {
        pil_block *b = &s->table[k];
        if (b->key == key)
            return b;
        if (b->key == 0)
            return NULL;
        k = (k + 1) & s->mask;
    }
}

static pil_block *pil_place(pil_block *table, uint64_t mask, uint32_t key)
{
    uint64_t k = pil_slot(key, mask);
    while (table[k].key != 0 && table[k].key != key)
        k = (k + 1) & mask;
    return &table[k];
}

PIL_EXPORT pil_state *pil_new(void *emu_stop, void *reg_read, void *slow_block, void *slow_check,
                              int64_t lazy_fp_stacking)
{
    pil_state *s = calloc(1, sizeof *s);
    if (s == NULL)
        return NULL;
    s->mask = 1023;
    s->table = calloc(s->mask + 1, sizeof *s->table);
    if (s->table == NULL) {
        free(s);
        return NULL;
    }
    s->emu_stop = (pil_uc_emu_stop)emu_stop;
    s->reg_read = (pil_uc_reg_read)reg_read;
    s->slow_block = (pil_slow_block)slow_block;
    s->slow_check = (pil_slow_check)slow_check;
    s->lazy_fp_stacking = lazy_fp_stacking;
    s->prev_fallthrough = -1;
    s->tail_cycles = -1;
    s->framework_lo = s->framework_hi = -1;
    return s;
}

PIL_EXPORT void pil_free(pil_state *s)
{
    if (s != NULL) {
        free(s->table);
        free(s);
    }
}

PIL_EXPORT uint64_t pil_state_size(void)
{
    return sizeof(pil_state);
}

/* Insert or replace the entry of the block at address; 0, or -1 when memory ran out (the block then
   stays Python's). The table doubles at half full. */
PIL_EXPORT int pil_insert(pil_state *s, uint64_t address, uint32_t size, uint32_t cycles, uint32_t count,
                          uint32_t taken_extra, uint32_t entry_extra, int32_t softfloat, uint32_t flags)
{
    uint32_t key = (uint32_t)address + 1u;
    if (softfloat >= PIL_SOFT_FLOAT_MAX)
        flags |= PIL_PYTHON;
    if ((s->used + 1) * 2 > s->mask + 1) {
        uint64_t mask = s->mask * 2 + 1;
        pil_block *table = calloc(mask + 1, sizeof *table);
        if (table == NULL)
            return -1;
        for (uint64_t k = 0; k <= s->mask; k++)
            if (s->table[k].key != 0)
                *pil_place(table, mask, s->table[k].key) = s->table[k];
        free(s->table);
        s->table = table;
        s->mask = mask;
    }
    pil_block *b = pil_place(s->table, s->mask, key);
    if (b->key == 0)
        s->used++;
    b->key = key;
    b->size = size;
    b->cycles = cycles;
    b->count = count;
    b->taken_extra = taken_extra;
    b->entry_extra = entry_extra;
    b->softfloat = softfloat;
    b->flags = flags;
    return 0;
}

/* UC_HOOK_BLOCK: Core._on_block and Core._special without a fault. */
PIL_EXPORT void pil_block_hook(void *uc, uint64_t address, uint32_t size, void *user)
{
    pil_state *s = user;
    if (s->tail_cycles < 0 && (int64_t)address >= s->framework_lo && (int64_t)address < s->framework_hi) {
        s->tail_cycles = s->cycles; /* the firmware's part of the call ends here */
        s->tail_instructions = s->instructions;
        s->charge = 0;
    }
    const pil_block *b = pil_find(s, address);
    if (b == NULL || b->size != size || (b->flags & PIL_PYTHON)) {
        s->slow_block(address, size);
        return;
    }
    if (s->cycles >= (s->tail_cycles < 0 ? s->stop_at : s->hang_at)) {
        s->emu_stop(uc); /* this block has not run: it is charged when the call resumes */
        return;
    }
    s->cycles += b->cycles;
    if ((int64_t)address != s->prev_fallthrough)
        s->cycles += s->prev_taken_extra + (int64_t)b->entry_extra;
    s->instructions += b->count;
    s->prev_fallthrough = (int64_t)(address + size);
    s->prev_taken_extra = b->taken_extra;
    if (b->flags & PIL_FP) {
        s->uses_fp = 1;
        if (s->fp_frame && !s->lazy_stacked && s->charge) {
            s->lazy_stacked = 1; /* the FP context is pushed at the handler's first FP instruction */
            s->cycles += s->lazy_fp_stacking;
        }
    }
    if (b->softfloat >= 0 && s->charge) {
        s->softfloat_counts[b->softfloat]++;
        s->softfloat_dirty = 1;
    }
}

/* UC_HOOK_CODE on one checked instruction: Core._on_check's test; a fault goes to Python. */
PIL_EXPORT void pil_check_hook(void *uc, uint64_t address, uint32_t size, void *user)
{
    const pil_check *c = user;
    union {
        uint64_t wide;
        uint32_t word;
    } value;
    value.wide = 0;
    c->state->reg_read(uc, c->reg, &value);
    uint32_t at = value.word + c->offset;
    if (c->kind != 0 && c->index_reg != 0) {
        value.wide = 0;
        c->state->reg_read(uc, c->index_reg, &value);
        at += value.word;
    }
    int bad = c->kind == 0 ? value.word == 0 : (at & c->mask) != 0;
    if (bad)
        c->state->slow_check(address, size, c->index);
}
