//! The part of the C library a Cortex-M firmware links that Zig's compiler-rt does not carry.
//!
//! A target build (hil/pil/build.py) links with `zig cc -target thumb-freestanding-eabi[hf]`,
//! which brings compiler-rt for the core: the run-time ABI (__aeabi_* soft float, 64-bit
//! division), memcpy/memmove/memset, and the C maths functions Zig keeps there (sin, cos, tan,
//! exp, exp2, log, log2, log10, sqrt, fabs, floor, ceil, round, trunc, fmod, fma, fmin, fmax in
//! float and double). This file exports the rest of C99's <math.h> that firmware commonly uses,
//! and a few <string.h> functions, from Zig's standard library (std.math, std.mem), built for the
//! same core and float ABI. Every symbol is weak: a firmware's own definition wins.

const std = @import("std");
const math = std.math;

fn weak(comptime f: anytype, comptime name: []const u8) void {
    @export(f, .{ .name = name, .linkage = .weak });
}

fn unary(comptime T: type, comptime f: anytype) fn (T) callconv(.c) T {
    return struct {
        fn g(x: T) callconv(.c) T {
            return f(x);
        }
    }.g;
}

fn binary(comptime T: type, comptime f: anytype) fn (T, T) callconv(.c) T {
    return struct {
        fn g(x: T, y: T) callconv(.c) T {
            return f(x, y);
        }
    }.g;
}

fn powT(comptime T: type) fn (T, T) T {
    return struct {
        fn g(x: T, y: T) T {
            return math.pow(T, x, y);
        }
    }.g;
}

fn nextafterT(comptime T: type) fn (T, T) T {
    return struct {
        fn g(x: T, y: T) T {
            return math.nextAfter(T, x, y);
        }
    }.g;
}

fn fdimT(comptime T: type) fn (T, T) T {
    return struct {
        fn g(x: T, y: T) T {
            if (math.isNan(x) or math.isNan(y)) return x + y;
            return if (x > y) x - y else 0;
        }
    }.g;
}

fn ldexpT(comptime T: type) fn (T, c_int) callconv(.c) T {
    return struct {
        fn g(x: T, n: c_int) callconv(.c) T {
            return math.ldexp(x, n);
        }
    }.g;
}

fn frexpT(comptime T: type) fn (T, *c_int) callconv(.c) T {
    return struct {
        fn g(x: T, e: *c_int) callconv(.c) T {
            const r = math.frexp(x);
            e.* = r.exponent;
            return r.significand;
        }
    }.g;
}

fn modfT(comptime T: type) fn (T, *T) callconv(.c) T {
    return struct {
        fn g(x: T, ip: *T) callconv(.c) T {
            const r = math.modf(x);
            ip.* = r.ipart;
            return r.fpart;
        }
    }.g;
}

fn lroundT(comptime T: type) fn (T) callconv(.c) c_long {
    return struct {
        fn g(x: T) callconv(.c) c_long {
            return @intFromFloat(@round(x));
        }
    }.g;
}

fn ilogbT(comptime T: type) fn (T) callconv(.c) c_int {
    return struct {
        fn g(x: T) callconv(.c) c_int {
            return math.ilogb(x);
        }
    }.g;
}

fn both(comptime name: []const u8, comptime f: anytype) void {
    weak(&unary(f32, f), name ++ "f");
    weak(&unary(f64, f), name);
}

fn both2(comptime name: []const u8, comptime f32f: anytype, comptime f64f: anytype) void {
    weak(&binary(f32, f32f), name ++ "f");
    weak(&binary(f64, f64f), name);
}

fn memcmp(a: [*]const u8, b: [*]const u8, n: usize) callconv(.c) c_int {
    for (0..n) |i| {
        if (a[i] != b[i]) return @as(c_int, a[i]) - @as(c_int, b[i]);
    }
    return 0;
}

fn strlen(s: [*:0]const u8) callconv(.c) usize {
    return std.mem.len(s);
}

fn strncmp(a: [*]const u8, b: [*]const u8, n: usize) callconv(.c) c_int {
    for (0..n) |i| {
        if (a[i] != b[i] or a[i] == 0) return @as(c_int, a[i]) - @as(c_int, b[i]);
    }
    return 0;
}

fn strcmp(a: [*]const u8, b: [*]const u8) callconv(.c) c_int {
    return strncmp(a, b, math.maxInt(usize));
}

comptime {
    both("acos", math.acos);
    both("asin", math.asin);
    both("atan", math.atan);
    both("sinh", math.sinh);
    both("cosh", math.cosh);
    both("tanh", math.tanh);
    both("asinh", math.asinh);
    both("acosh", math.acosh);
    both("atanh", math.atanh);
    both("cbrt", math.cbrt);
    both("expm1", math.expm1);
    both("log1p", math.log1p);
    both2("atan2", math.atan2, math.atan2);
    both2("hypot", math.hypot, math.hypot);
    both2("copysign", math.copysign, math.copysign);
    both2("pow", powT(f32), powT(f64));
    both2("nextafter", nextafterT(f32), nextafterT(f64));
    both2("fdim", fdimT(f32), fdimT(f64));
    weak(&ldexpT(f32), "ldexpf");
    weak(&ldexpT(f64), "ldexp");
    weak(&ldexpT(f32), "scalbnf");
    weak(&ldexpT(f64), "scalbn");
    weak(&frexpT(f32), "frexpf");
    weak(&frexpT(f64), "frexp");
    weak(&modfT(f32), "modff");
    weak(&modfT(f64), "modf");
    weak(&lroundT(f32), "lroundf");
    weak(&lroundT(f64), "lround");
    weak(&ilogbT(f32), "ilogbf");
    weak(&ilogbT(f64), "ilogb");
    weak(&memcmp, "memcmp");
    weak(&strlen, "strlen");
    weak(&strcmp, "strcmp");
    weak(&strncmp, "strncmp");
}
