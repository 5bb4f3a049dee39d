#!/usr/bin/env python3
"""The launch files as roslaunch reads them (its own loader, no master, nothing started):
use_sim_time is set only when given, so a parent's value survives an include; rviz's topics follow
the node's name; manager:= loads the nodelet instead of the plain node; replay.launch runs under
simulated time.  Results go where --gtest_output=xml:FILE says (rosunit), for catkin and ctest."""
import os
import re
import sys
import unittest

import roslaunch.config
import rosunit

PACKAGE_DIR = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
MAP_CORRECTOR = os.path.join(PACKAGE_DIR, 'launch', 'map_corrector.launch')
REPLAY = os.path.join(PACKAGE_DIR, 'launch', 'replay.launch')
RVIZ_CONFIG = os.path.join(PACKAGE_DIR, 'rviz', 'map_corrector.rviz')


def load(path=None, args=None, wrapper=None):
    """The launch configuration of `path` with `args`, or of the launch XML string `wrapper`."""
    files = [(path, args or [])] if path else []
    return roslaunch.config.load_config_default(files, None, roslaunch_strs=[wrapper] if wrapper else None)


def node(config, type_):
    found = [n for n in config.nodes if n.type == type_]
    return found[0] if len(found) == 1 else None


def rviz_topics():
    with open(RVIZ_CONFIG) as f:
        return re.findall(r'^\s*(?:Marker )?Topic: (\S+)\s*$', f.read(), re.MULTILINE)


class LaunchFiles(unittest.TestCase):
    def test_use_sim_time_is_left_alone_unless_given(self):
        self.assertNotIn('/use_sim_time', load(MAP_CORRECTOR).params)
        for value in (True, False):
            config = load(MAP_CORRECTOR, ['use_sim_time:=%s' % str(value).lower()])
            self.assertIs(config.params['/use_sim_time'].value, value)

    def test_a_parents_use_sim_time_survives_the_include(self):
        wrapper = ('<launch><param name="/use_sim_time" value="true"/>'
                   '<include file="%s"/></launch>' % MAP_CORRECTOR)
        self.assertIs(load(wrapper=wrapper).params['/use_sim_time'].value, True)

    def test_rviz_shows_the_topics_of_the_named_node(self):
        topics = rviz_topics()
        self.assertEqual(sorted(topics), ['graph_markers', 'path', 'pose'])
        for t in topics:
            self.assertFalse(t.startswith('/'), 'rviz/map_corrector.rviz hard-codes %s' % t)
        self.assertIsNone(node(load(MAP_CORRECTOR), 'rviz'))  # off by default
        config = load(MAP_CORRECTOR, ['rviz:=true', 'node_name:=corrector'])
        rviz = node(config, 'rviz')
        self.assertIsNotNone(rviz)
        self.assertEqual(sorted(tuple(r) for r in rviz.remap_args), sorted((t, 'corrector/' + t) for t in topics))
        self.assertEqual(node(config, 'map_corrector_node').name, 'corrector')

    def test_manager_loads_the_nodelet_instead_of_the_node(self):
        config = load(MAP_CORRECTOR, ['manager:=toro_manager', 'odom_topic:=/odometry/filtered'])
        self.assertIsNone(node(config, 'map_corrector_node'))
        nodelet = node(config, 'nodelet')
        self.assertIsNotNone(nodelet)
        self.assertEqual(nodelet.name, 'map_corrector')
        self.assertEqual(nodelet.args.split(), ['load', 'toro_ros/MapCorrectorNodelet', 'toro_manager'])
        self.assertIn(('odom', '/odometry/filtered'), [tuple(r) for r in nodelet.remap_args])
        # The same parameters as the plain node (its private namespace is the nodelet's name).
        self.assertEqual(config.params['/map_corrector/keyframe_distance_m'].value, 0.5)

    def test_replay_runs_under_simulated_time(self):
        config = load(REPLAY, ['bag:=/tmp/none.bag'])
        self.assertIs(config.params['/use_sim_time'].value, True)
        self.assertIsNotNone(node(config, 'map_corrector_node'))


if __name__ == '__main__':
    rosunit.unitrun('toro_ros', 'test_launch_files', LaunchFiles)
