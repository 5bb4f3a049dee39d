#!/usr/bin/python3
"""Pictures of a toro_offline run, from its summary.json:

  plot_trajectory.py out/offline/summary.json [-o out/offline/trajectory.png] [--title T]

One PNG with the trajectory before (the keyframes' odometry) and after (the corrected map), and
the truth when the bag came with one, in a top view (x-y) and a side view (x-z); loop closures are
drawn between the corrected keyframes they join, coloured by their chi2 after correction; and the
error curve: g2o chi2 per constraint after every optimisation pass (online passes while the bag
played, then the final full passes).  Needs python3-matplotlib (Debian); run with /usr/bin/python3.
"""
import argparse
import json
import os
import sys

import matplotlib
matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402


def column(keyframes, key, axis):
    return [k[key][axis] for k in keyframes if key in k]


def draw_view(ax, summary, axes, names):
    keyframes = summary['trajectory']
    a, b = axes
    ax.plot(column(keyframes, 'odometry', a), column(keyframes, 'odometry', b), '--', color='0.55', lw=1.0,
            label='odometry (before)')
    if any('truth' in k for k in keyframes):
        ax.plot(column(keyframes, 'truth', a), column(keyframes, 'truth', b), color='tab:green', lw=2.5,
                alpha=0.45, label='truth')
    ax.plot(column(keyframes, 'corrected', a), column(keyframes, 'corrected', b), color='tab:blue', lw=1.2,
            label='corrected (after)')
    closures = summary['loop_closures']
    if closures:
        segments = [[(keyframes[c['from']]['corrected'][a], keyframes[c['from']]['corrected'][b]),
                     (keyframes[c['to']]['corrected'][a], keyframes[c['to']]['corrected'][b])] for c in closures]
        residual = [c['chi2_after'] if c['chi2_after'] is not None else 0.0 for c in closures]
        lines = LineCollection(segments, cmap='plasma', linewidths=1.5, zorder=3)
        lines.set_array(residual)
        ax.add_collection(lines)
        return lines
    ax.set_xlabel(names[0] + ' [m]')
    ax.set_ylabel(names[1] + ' [m]')
    return None


def draw_curve(ax, summary):
    curve = summary['curve']
    if not curve:
        ax.text(0.5, 0.5, 'no optimisation pass ran', ha='center', transform=ax.transAxes)
        return
    for final, colour, label in ((False, 'tab:blue', 'online passes (while the bag played)'),
                                 (True, 'tab:red', 'final full passes')):
        points = [p for p in curve if p['final'] == final and p['chi2'] is not None and p['constraints'] > 0]
        if points:
            ax.plot([p['pass'] for p in points], [p['chi2'] / p['constraints'] for p in points], '.-', color=colour,
                    ms=3, lw=1, label=label)
    if summary['constraints']:
        ax.axhline(summary['chi2_odometry'] / summary['constraints'], color='0.55', ls='--', lw=1,
                   label='odometry only (before)')
    ax.set_yscale('log')
    ax.set_xlabel('optimisation pass')
    ax.set_ylabel('g2o chi2 / constraint')
    ax.legend(fontsize=8)
    ax.grid(True, which='both', alpha=0.3)


def title_of(summary, given):
    if given:
        return given
    text = '%s: %d keyframes, %d loop closures applied (%d refused), chi2 %.4g -> %.4g' % (
        os.path.basename(summary['bag']), summary['keyframes'], summary['loop_closures_applied'],
        summary['loop_closures_refused'], summary['chi2_odometry'], summary['chi2_corrected'])
    if 'score' in summary:
        text += '\nposition RMSE vs truth: odometry %.3g m -> corrected %.3g m' % (
            summary['score']['odometry']['rmse_m'], summary['score']['corrected']['rmse_m'])
    return text


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('summary', help="toro_offline's summary.json")
    parser.add_argument('-o', '--output', help='PNG to write (default: trajectory.png beside the summary)')
    parser.add_argument('--title', default='')
    parser.add_argument('--dpi', type=int, default=110, help='resolution (default 110: 1430 x 990 pixels)')
    args = parser.parse_args()
    try:
        with open(args.summary) as f:
            summary = json.load(f)
    except (OSError, ValueError) as e:
        sys.exit('plot_trajectory.py: %s: %s' % (args.summary, e))
    if not summary.get('trajectory'):
        sys.exit('plot_trajectory.py: %s: no keyframes to draw' % args.summary)
    output = args.output or os.path.join(os.path.dirname(args.summary) or '.', 'trajectory.png')

    fig = plt.figure(figsize=(13, 9))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.6, 1])
    top, side, curve = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, :])
    lines = draw_view(top, summary, (0, 1), ('x', 'y'))
    draw_view(side, summary, (0, 2), ('x', 'z'))
    for ax, name, labels in ((top, 'top view', ('x', 'y')), (side, 'side view', ('x', 'z'))):
        ax.set_title(name)
        ax.set_xlabel(labels[0] + ' [m]')
        ax.set_ylabel(labels[1] + ' [m]')
        ax.grid(True, alpha=0.3)
        ax.autoscale()
    top.set_aspect('equal', adjustable='datalim')
    top.legend(fontsize=8, loc='best')
    if lines is not None:
        fig.colorbar(lines, ax=[top, side], shrink=0.8, label='loop closure chi2 after correction')
    draw_curve(curve, summary)
    fig.suptitle(title_of(summary, args.title), fontsize=10)
    os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
    fig.savefig(output, dpi=args.dpi)
    print('wrote %s' % output)


if __name__ == '__main__':
    main()
